#!/usr/bin/python3
# (The system interpreter, not `env python3`: a python3 from pyenv or a venv
# first on PATH has no rospy.)
"""End to end (started by test/atlas_merge.test): two maps, merged, and a VO across the merge.

Renders atlas_scene.yaml: `walker` and `walker_b` start within a second of each other (walker
first, so that it makes the first map) on opposite sides of the small ring; `walker` draws a line on the wall at the east end of the south corridor (frames
100-110), long before `walker_b` comes round to the south corridor. Plays both through the real
server and devices and asserts that
- each device is tracked within 10 uploads of starting, in a map of its own (the LocalGraphs'
  map_id differ), neither waiting for the other;
- the maps merge: later graphs of both devices carry one map id;
- one similarity fits both devices' poses in the merged map to the ground truth: each device's
  median error within 10 cm (a wrong merge leaves metres);
- `walker_b` receives the line after the merge (in a graph of the merged map) and draws it where
  it was touched (x = 9, y 0.9-1.5, z = 1.2): the object's map position seen from walker_b's
  server pose of the frame that brought it, put in the world through that frame's ground-truth
  pose (what the user of walker_b sees). Within 20 cm on its last SETTLED_GRAPHS graphs with
  it, within 40 cm on every one (a wrong merge is metres off); both reported, beside where walker
  itself drew it.

Private params: ~scene, ~player_launch, ~frames.
"""

import os
import sys
import time
import unittest

import numpy as np
import rospy
import rostest
from ecar_msgs.msg import InteractionResult, LocalGraph
from ecar_sim import ground_truth
from ecar_sim.alignment import Similarity, quat_to_rot, umeyama
from ecar_sim.playback import Playback

PKG = "ecar_sim"
DEVICES = ["walker", "walker_b"]
EVERY = 4  # uploads: every 4th frame
# Graphs of walker_b right after the merge: its pose comes from the merge's similarity (refitted
# on the welded seam's reprojections, refitSeam) until the global adjustment after the merge and
# its next relocalisations settle it. And walker_b closes the ring's loop (with walker's first
# keyframe) shortly before it sees the line: until that loop's correction and the global
# adjustment after it land on the loop-closer thread, the ring's drift lies between walker_b and
# the line (the loop moves walker_b's keyframe 5-15 cm). When they land depends on the CPU, not
# on the data: alone, walker_b's first graphs with the line drew it 5-12 cm off; in a full suite
# run its first 9 graphs drew it 28-32 cm off, then 10-13 cm once the loop landed (server log:
# "loop closed ... moved 0.148 m") and 3-5 cm once its global adjustment did (frame 356 on).
# So every graph is bounded by 40 cm (a wrong merge leaves metres), and the settled error is
# measured on the last graphs, after the corrections landed: 3.6-9.9 cm in six runs. What is
# left then grows with walker_b's distance from the line (about 10 m at its last frames) times
# the map's scale error, which follows the simulated odometry's +1% bias (1.0-1.6% measured):
# 10-16 cm at worst; so 20 cm.
SETTLED_GRAPHS = 10
FIRST_GRAPHS_BOUND = 0.40
SETTLED_BOUND = 0.20


class AtlasMergeTest(unittest.TestCase):
    def setUp(self):
        self.scene = rospy.get_param("~scene")
        self.player_launch = rospy.get_param("~player_launch")
        self.frames = int(rospy.get_param("~frames", 430))
        self.playback = Playback(self.scene, self.player_launch, self.frames, DEVICES,
                                 prefix="ecar_atlas_merge_")
        self.lock = self.playback.lock
        # Per device: frame_index -> (map_id, position) of tracked graphs, and
        # (frame_index, map_id, object) of every object received.
        self.poses = {d: {} for d in DEVICES}
        self.full_poses = {d: {} for d in DEVICES}
        self.objects = {d: [] for d in DEVICES}
        self.graph_count = {d: 0 for d in DEVICES}
        self.results = []

    def tearDown(self):
        self.playback.close()

    def on_graph(self, m, device):
        with self.lock:
            self.graph_count[device] += 1
            if m.status in (LocalGraph.OK, LocalGraph.RELOCALISED):
                p, q = m.pose.position, m.pose.orientation
                T = np.eye(4)
                T[:3, :3] = quat_to_rot([q.x, q.y, q.z, q.w])
                T[:3, 3] = [p.x, p.y, p.z]
                self.poses[device][m.frame_index] = (m.map_id, np.array([p.x, p.y, p.z]))
                self.full_poses[device][m.frame_index] = T
                for o in m.objects:
                    self.objects[device].append((m.frame_index, m.map_id, o))
            self.playback.activity()

    def on_result(self, m):
        with self.lock:
            self.results.append(m)

    def test_two_maps_merge_and_a_vo_crosses(self):
        datasets = self.playback.render_all()
        self.assertTrue(os.path.exists(os.path.join(datasets["walker"], "touches.txt")),
                        "walker's dataset has no touches.txt")
        rospy.Subscriber("/walker/interaction_result", InteractionResult, self.on_result,
                         queue_size=1000)
        for d in DEVICES:
            rospy.Subscriber("/%s/local_graph" % d, LocalGraph, self.on_graph, callback_args=d,
                             queue_size=500)
        # walker first, walker_b once walker's first graph is back: walker then makes the first
        # map, and walker_b, a second one of its own at once. (The other order, walker_b's map
        # first, is measured worse and is open: walker then draws its own line 12 cm off, where
        # the SLAM map alone is as good, and after the merge walker_b saw it up to 35 cm off.)
        # Both players preload before either starts: walker_b's player preloading only after
        # walker's first graph (5 s alone, 13 s under load in CI) let walker map the ground
        # around walker_b's start, and walker_b began in walker's map.
        # walker_b goes once walker is tracked (its map exists), not at walker's first graph:
        # that one may come before walker's map is made (LOST while initialising), and walker_b
        # then made map 1 (a CI failure: the maps never merged).
        self.playback.start(datasets, held=True)
        self.playback.release(["walker"])
        deadline = time.time() + 120.0
        while time.time() < deadline and not rospy.is_shutdown():
            with self.lock:
                if self.poses["walker"]:
                    break
            time.sleep(0.05)
        self.playback.release(["walker_b"])
        finished = self.playback.wait(400.0)
        self.assertTrue(all(finished.values()), "players did not finish: %s" % finished)

        # Each device tracked early, each in its own map (the scene's start pause is 15 frames).
        first = {}
        for d in DEVICES:
            frames = sorted(self.poses[d])
            self.assertTrue(frames, "%s was never tracked" % d)
            first[d] = frames[0]
            self.assertLessEqual(frames[0], 15 + 10 * EVERY,
                                 "%s first tracked at frame %d" % (d, frames[0]))
        start_maps = {d: self.poses[d][first[d]][0] for d in DEVICES}
        self.assertNotEqual(start_maps["walker"], start_maps["walker_b"],
                            "both devices started in map %s" % start_maps)
        self.assertNotIn(0, start_maps.values())

        # The maps merged: the last graphs of both are in one map. (Open: beside a busy loop at
        # nice 0 the mapper, niced by background_nice, falls behind and a device loses tracking at
        # its first corner, frames 152-160; its new map merges into the other device's, which
        # later relocalises into the abandoned one, and 4 of 9 such runs ended in two maps here.
        # Not without that load, which CI does not add: its live tests run one at a time.)
        last = {d: self.poses[d][max(self.poses[d])][0] for d in DEVICES}
        self.assertEqual(last["walker"], last["walker_b"], "maps at the end: %s" % last)
        merged = last["walker"]
        merged_at = min(f for f, (m, _) in self.poses["walker_b"].items() if m == merged
                        and start_maps["walker_b"] != merged) \
            if start_maps["walker_b"] != merged else \
            min(f for f, (m, _) in self.poses["walker"].items() if m == merged)
        rospy.loginfo("maps at the start %s, merged into map %d (first graph in it at frame %d)",
                      start_maps, merged, merged_at)

        # One similarity fits both devices' poses in the merged map to the ground truth.
        src, dst, who = [], [], []
        for d in DEVICES:
            gt = ground_truth.read_groundtruth(datasets[d])
            for f, (m, p) in sorted(self.poses[d].items()):
                if m == merged:
                    src.append(p)
                    dst.append(gt[f][:3, 3])
                    who.append((d, f))
        sim = Similarity(*umeyama(src, dst))
        err = np.array([np.linalg.norm(sim.apply(s) - t) for s, t in zip(src, dst)])
        rmse = float(np.sqrt((err ** 2).mean()))
        rospy.loginfo("merged map: %d poses, one-similarity RMSE %.3f m, median %.3f m, max %.3f m",
                      len(src), rmse, float(np.median(err)), float(err.max()))
        # Where the error lies: per device, in tenths of its graphs in the merged map.
        errors = {d: [x for x, (dd, _) in zip(err, who) if dd == d] for d in DEVICES}
        for d in DEVICES:
            e, f = errors[d], [ff for dd, ff in who if dd == d]
            parts = [(f[i * len(f) // 10], round(float(np.sqrt(np.mean(np.square(c)))), 3))
                     for i, c in enumerate(np.array_split(np.array(e), 10)) if len(c)]
            rospy.loginfo("merged map, %s: %d poses, RMSE per tenth (first frame, m) %s",
                          d, len(e), parts)
        # A wrong merge leaves metres. A right one: 1.6-5.5 cm RMSE over all graphs in 9 runs
        # here (5 of them beside a busy core). But that RMSE holds walker_b's first graphs in the
        # merged map, posed before the merge's global adjustment and the ring's loop correction
        # land on the loop-closer thread, and when they land depends on the CPU, not on the data:
        # beside a busy core a tenth of walker_b's graphs was 18 cm off (RMSE; 41 cm, one graph
        # 79 cm, with the mapper not niced) while its other tenths were 1-5 cm; CI on 6cb5b6b
        # measured 10.9 cm RMSE. So the median (the graphs after the corrections) is bounded,
        # per device: 1.3-5.2 cm over both in the four runs that logged it, walker's 5.3 cm the
        # worst (beside a busy core, mapper not niced). Issue 12's target is 3 cm, measured by
        # the benchmark, not here.
        for d in DEVICES:
            e = errors[d]
            self.assertTrue(e, "%s has no graph in the merged map" % d)
            self.assertLess(float(np.median(e)), 0.10, "one similarity fits %s's graphs in the "
                            "merged map within %.3f m (median)" % (d, float(np.median(e))))

        # walker drew the line (accepted), before the merge.
        accepted = [r for r in self.results if r.accepted]
        self.assertGreaterEqual(len(accepted), 1, "walker's touches: %s" %
                                [(r.request_id, r.reason) for r in self.results])
        # walker_b received it after the merge, in the merged map, where it was drawn.
        received = [(f, o) for f, m, o in self.objects["walker_b"] if m == merged and
                    start_maps["walker_b"] != merged]
        if start_maps["walker_b"] == merged:  # walker's map went into walker_b's
            received = [(f, o) for f, m, o in self.objects["walker_b"]]
        self.assertTrue(received, "walker_b received no object after the merge")
        # Where each device's user sees an object: its map position through the device's
        # server pose of the frame that brought it, put in the world by that frame's
        # ground-truth pose; its error is the distance to the touched stroke.
        gts = {d: ground_truth.read_groundtruth(datasets[d]) for d in DEVICES}

        def drawn_at(device, f, v):
            return (gts[device][f] @ np.linalg.inv(self.full_poses[device][f]) @
                    np.array([v.x, v.y, v.z, 1.0]))[:3]

        def off_stroke(p):
            """Distance (m) of p to the stroke x = 9, y 0.9-1.5, z = 1.2."""
            return float(np.linalg.norm(p - np.array([9.0, min(max(p[1], 0.9), 1.5), 1.2])))

        own = [off_stroke(drawn_at("walker", f, v)) for f, m, o in self.objects["walker"]
               if m == start_maps["walker"] for v in (o.start, o.end)]
        per_frame = {}
        for f, o in received:
            for v in (o.start, o.end):
                per_frame[f] = max(per_frame.get(f, 0.0), off_stroke(drawn_at("walker_b", f, v)))
        frames_b = sorted(per_frame)
        settled = [per_frame[f] for f in frames_b[-SETTLED_GRAPHS:]]
        rospy.loginfo("walker_b's graphs with the line: frames %s; its last tracked frame %d",
                      frames_b, max(self.poses["walker_b"]))
        rospy.loginfo("walker drew the line within %.3f m of the touch; walker_b, after the merge, "
                      "draws it within %.3f m on all %d graphs with it and within %.3f m on the "
                      "last %d; per frame %s", max(own or [0.0]), max(per_frame.values()),
                      len(frames_b), max(settled or [0.0]), len(settled),
                      {f: round(e, 3) for f, e in sorted(per_frame.items())})
        self.assertLess(max(per_frame.values()), FIRST_GRAPHS_BOUND,
                        "a wrong merge (walker_b's first graph in the merged map at frame %d): %s"
                        % (merged_at, per_frame))
        self.assertGreaterEqual(len(frames_b), 2 * SETTLED_GRAPHS,
                                "walker_b held the line on %d graphs" % len(frames_b))
        # Issue 12's 2 cm target is the benchmark's, not this test's. A merge that did not move
        # the line (walker's map merged into walker_b's: S moves it by metres) or put it in the
        # wrong map fails here, and so does a loop correction that never reaches the line.
        self.assertLess(max(settled), SETTLED_BOUND, "walker_b draws the line %.3f m off on its "
                        "last %d graphs; per frame %s" % (max(settled), len(settled), {
                            f: round(e, 3) for f, e in sorted(per_frame.items())}))


if __name__ == "__main__":
    rospy.init_node("atlas_merge_test")
    rostest.rosrun(PKG, "atlas_merge", AtlasMergeTest, sys.argv)
