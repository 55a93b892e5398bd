"""Virtual-object (VO) sync metrics of one session, computed against ground truth.

Used by `run_session`; needs no running ROS, so it is tested on synthetic inputs
(test/vo_metrics_test.py). The scene, camera and ground truth are `ground_truth`'s, the
plane check is in `plane_metrics`, the fit in `alignment`.

Definitions (all times are wall-clock seconds on the session's one machine):

- A VO state (id, version) exists from the moment the server accepted it, as
  seen on /ecar/objects.
- Each VO is put into the dataset world with the Sim(3) that best fits the
  server's camera positions (map frame) to the ground truth (world frame).
- A VO is *expected* on a device frame when the device has received its first
  local graph, the VO's state from `grace` seconds earlier is live (not
  deleted), and that state is visible from the frame's ground-truth camera and
  was already visible from the device's frame `grace` seconds earlier (what just
  came into view reaches the device with the graph of an upload that sees it;
  `success_strict` per device drops this condition). Visible means: one
  of its points (LINE: start, centre, end; ANCHOR: position) projects into the
  image in front of the camera, lies within `max_range` metres, and the straight
  line from the camera to it stays in the scene's free space (no wall or solid in
  between). `grace` is two of the device's round trips (twice its median
  interval between local graphs): a change reaches a device with the local
  graph of its next upload, or at worst the one after.
- The frame is a *success* when the device holds that VO at that version or a
  newer one.
- Distance bins (2 m) use the ground-truth distance from the camera to the VO's
  centre; angle bins (15 deg) the angle around the VO's centre, seen from
  above, between the registering device's camera at registration and the
  receiving camera (a device circling the VO through 180 degrees covers every
  bin).
- Interaction-to-visible latency: for every accepted change of a VO, and every
  other device whose ground-truth view showed the VO at that moment, the time
  until that device first held the version (or a newer one), in seconds and in
  that device's round trips. The change's time is when the session's collector
  got it from the server (/ecar/objects); the device's is when the version
  arrived on it (DeviceFrame.object_received; without it, the first frame that
  held it). Both are wall clocks of the one machine; a device that got it before
  the collector counts 0.
- Position agreement: where a device draws a VO in the real world, that is the
  VO's map position seen from the device's own pose estimate, put into the world
  with the frame's ground-truth camera. For each VO version seen by two or more
  devices, the distance between their median drawn positions (over all frames,
  and over the frames within 10 m of the VO).
"""

import bisect
import math

import numpy as np
from ecar_msgs.msg import DeviceFrame, VirtualObject

from ecar_sim.alignment import quat_to_rot

DISTANCE_BIN_M = 2.0
ANGLE_BIN_DEG = 15.0


# ---------------------------------------------------------------- inputs


class VoState:
    """One accepted state of a VO (map frame)."""

    __slots__ = ("id", "version", "deleted", "owner", "kind", "position", "start", "end", "wall")

    def __init__(self, id, version, deleted, owner, kind, position, start, end, wall):
        self.id, self.version, self.deleted = id, version, deleted
        self.owner, self.kind = owner, kind
        self.position = np.asarray(position, float)
        self.start = np.asarray(start, float)
        self.end = np.asarray(end, float)
        self.wall = wall

    def points(self):
        """LINE: start, centre, end; ANCHOR: its position."""
        if self.kind == VirtualObject.LINE:
            return [self.start, self.position, self.end]
        return [self.position]

    def centre_index(self):
        """Where its centre is in points()."""
        return 1 if self.kind == VirtualObject.LINE else 0


class Timeline:
    """Every accepted state of every VO, by id, in version order."""

    def __init__(self, states):
        self.by_id = {}
        for s in sorted(states, key=lambda s: (s.id, s.version)):
            self.by_id.setdefault(s.id, []).append(s)
        self._walls = {i: [s.wall for s in v] for i, v in self.by_id.items()}

    def at(self, object_id, wall):
        """The latest state accepted at or before `wall`, or None."""
        walls = self._walls[object_id]
        k = bisect.bisect_right(walls, wall)
        return self.by_id[object_id][k - 1] if k else None

    def version(self, object_id, version):
        """The state of that version, or None."""
        for s in self.by_id.get(object_id, []):
            if s.version == version:
                return s
        return None


class DeviceRecord:
    """What one device did and saw.

    frames: {frame_index: (wall, status, position, quaternion xyzw, {object_id: version}[,
            {object_id: wall time the held version arrived on the device}])},
            status: DeviceFrame.NOT_INITIALISED, OK or LOST; pose = the device's own estimate
            (map).
    gt:     {frame_index: (4x4 T_world_camera)}
    graph_walls: wall times of the local graphs received.
    """

    def __init__(self, name, camera, frames, gt, graph_walls):
        self.name, self.camera, self.frames, self.gt = name, camera, frames, gt
        self.graph_walls = sorted(graph_walls)

    def round_trip(self):
        """Median interval between local graphs (s), or None."""
        d = np.diff(self.graph_walls)
        return float(np.median(d)) if len(d) else None


# ---------------------------------------------------------------- evaluation


def arrival(frame, object_id, frame_wall):
    """When the object held in `frame` arrived on the device: the device's record of it
    (DeviceFrame.object_received) when the frame has one, else the frame's own arrival (a frame
    is published after the object came, so that overstates the latency by up to a frame)."""
    received = frame[5].get(object_id) if len(frame) > 5 else None
    return frame_wall if received is None else min(received, frame_wall)


def _pct(values, q):
    return float(np.percentile(values, q)) if len(values) else None


def _rate(ok, total):
    return round(ok / total, 4) if total else None


def _bins(counter, width, unit):
    out = []
    for b in sorted(counter):
        ok, total = counter[b]
        out.append({"bin": "%g-%g %s" % (b * width, (b + 1) * width, unit), "expected": total,
                    "held": ok, "success": _rate(ok, total)})
    return out


def _azimuth_deg(a, b):
    """Angle between two directions seen from above (world z up): how far around the VO the
    second view is from the first."""
    a = np.array([a[0], a[1], 0.0])
    b = np.array([b[0], b[1], 0.0])
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if na < 1e-9 or nb < 1e-9:
        return 0.0
    return math.degrees(math.acos(max(-1.0, min(1.0, float(a @ b) / (na * nb)))))


class VoEvaluator:
    """The VO sync metrics of one session (see the module's definitions): evaluate() gives
    summary.json's `vo`."""

    def __init__(self, timeline, devices, free_space, map_to_world, max_range=40.0):
        self.timeline = timeline
        self.devices = {d.name: d for d in devices}
        self.space = free_space
        self.sim = map_to_world
        self.max_range = max_range
        self._visible_cache = {}
        self._world_cache = {}

    def world_points(self, state):
        """The state's points (VoState.points) in the world."""
        key = (state.id, state.version)
        if key not in self._world_cache:
            self._world_cache[key] = [self.sim.apply(p) for p in state.points()]
        return self._world_cache[key]

    def visible(self, device, frame, state):
        """Ground-truth visibility of a VO state from a device frame."""
        key = (device.name, frame, state.id, state.version)
        hit = self._visible_cache.get(key)
        if hit is not None:
            return hit
        T = device.gt[frame]
        r_wc, eye = T[:3, :3], T[:3, 3]
        hit = False
        for p in self.world_points(state):
            if device.camera.in_view(r_wc.T @ (p - eye), self.max_range) and \
                    self.space.line_of_sight(eye, p):
                hit = True
                break
        self._visible_cache[key] = hit
        return hit

    def registration_eye(self, first):
        """World position of the registering device's camera when the VO was accepted."""
        owner = self.devices.get(first.owner)
        if owner is None:
            return None
        best = None
        for f, e in owner.frames.items():
            if f in owner.gt and (best is None or
                                  abs(e[0] - first.wall) < abs(best[1] - first.wall)):
                best = (f, e[0])
        return None if best is None else owner.gt[best[0]][:3, 3]

    def evaluate(self):
        """Success overall, per device, by distance and angle; latency; position agreement;
        each object (the dict of summary.json's `vo`)."""
        total = [0, 0]
        total_strict = [0, 0]
        by_device = {}
        by_distance = {}
        by_angle = {}
        reg_eyes = {}
        for oid, states in self.timeline.by_id.items():
            reg_eyes[oid] = self.registration_eye(states[0])
        drawn = {}  # (id, version) -> {device: [world positions]}
        for dev in self.devices.values():
            rt = dev.round_trip()
            grace = 2.0 * rt if rt else 0.0
            counts = [0, 0]
            strict = [0, 0]
            started = False
            order = sorted(dev.frames, key=lambda f: dev.frames[f][0])
            walls = [dev.frames[f][0] for f in order]
            for f in sorted(dev.frames):
                wall, status, pos, quat, held = dev.frames[f][:5]
                started = started or status != DeviceFrame.NOT_INITIALISED
                if not started or f not in dev.gt:
                    continue
                T = dev.gt[f]
                # The device's frame `grace` earlier: a VO that came into view since then may
                # not have reached it yet (it goes into the local graph of an upload that sees it).
                k = bisect.bisect_right(walls, wall - grace)
                earlier = order[k - 1] if k else None
                for oid in self.timeline.by_id:
                    state = self.timeline.at(oid, wall - grace)
                    if state is None or state.deleted or not self.visible(dev, f, state):
                        continue
                    ok = held.get(oid, 0) >= state.version
                    strict[0] += ok
                    strict[1] += 1
                    if earlier is None or earlier not in dev.gt or \
                            not self.visible(dev, earlier, state):
                        continue
                    counts[0] += ok
                    counts[1] += 1
                    if dev.name == state.owner:
                        continue
                    centre = self.world_points(state)[state.centre_index()]
                    dist = float(np.linalg.norm(centre - T[:3, 3]))
                    b = by_distance.setdefault(int(dist // DISTANCE_BIN_M), [0, 0])
                    b[0] += ok
                    b[1] += 1
                    eye0 = reg_eyes.get(oid)
                    if eye0 is not None:
                        ang = _azimuth_deg(eye0 - centre, T[:3, 3] - centre)
                        b = by_angle.setdefault(min(int(ang // ANGLE_BIN_DEG), 11), [0, 0])
                        b[0] += ok
                        b[1] += 1
                # Where the device drew each VO version it held (tracked frames only).
                if status != DeviceFrame.OK:
                    continue
                r_mc = quat_to_rot(quat)
                t_mc = np.asarray(pos, float)
                for oid, version in held.items():
                    state = self.timeline.version(oid, version)
                    if state is None or not self.visible(dev, f, state):
                        continue
                    c = state.position
                    p_c = r_mc.T @ (c - t_mc) * self.sim.s
                    drawn.setdefault((oid, version), {}).setdefault(dev.name, []).append(
                        (T[:3, :3] @ p_c + T[:3, 3], float(np.linalg.norm(p_c))))
            by_device[dev.name] = {"expected": counts[1], "held": counts[0],
                                   "success": _rate(counts[0], counts[1]),
                                   "success_strict": _rate(strict[0], strict[1]),
                                   "grace_s": round(grace, 3)}
            total[0] += counts[0]
            total[1] += counts[1]
            total_strict[0] += strict[0]
            total_strict[1] += strict[1]

        receivers = [0, 0]
        for ok, n in by_distance.values():
            receivers[0] += ok
            receivers[1] += n
        return {
            "objects": len(self.timeline.by_id),
            "changes": sum(len(v) for v in self.timeline.by_id.values()),
            "success": _rate(total[0], total[1]),
            "expected_frames": total[1],
            "success_strict": _rate(total_strict[0], total_strict[1]),
            "success_other_devices": _rate(receivers[0], receivers[1]),
            "by_device": by_device,
            "by_distance": _bins(by_distance, DISTANCE_BIN_M, "m"),
            "by_angle": _bins(by_angle, ANGLE_BIN_DEG, "deg"),
            "latency": self.latency(),
            "position_agreement": self.agreement(drawn),
            "objects_detail": self.detail(),
        }

    def latency(self):
        """Accepted change -> first frame of another device that holds it."""
        seconds, trips = [], []
        missed = 0
        ordered = {d.name: sorted((e[0], f) for f, e in d.frames.items())
                   for d in self.devices.values()}
        walls = {name: [w for w, _ in v] for name, v in ordered.items()}
        for oid, states in self.timeline.by_id.items():
            for state in states:
                if state.deleted:
                    continue
                for dev in self.devices.values():
                    if dev.name == state.owner:
                        continue
                    frames = ordered[dev.name]
                    k = bisect.bisect_left(walls[dev.name], state.wall)
                    if k == len(frames):
                        continue
                    first = frames[k][1]
                    if first not in dev.gt or \
                            dev.frames[first][1] == DeviceFrame.NOT_INITIALISED or \
                            not self.visible(dev, first, state):
                        continue
                    got = next(((w, f) for w, f in frames[k:]
                                if dev.frames[f][4].get(oid, 0) >= state.version), None)
                    if got is None:
                        missed += 1
                        continue
                    got = arrival(dev.frames[got[1]], oid, got[0])
                    took = max(0.0, got - state.wall)
                    seconds.append(took)
                    rt = dev.round_trip()
                    if rt:
                        trips.append(took / rt)
        return {
            "changes_measured": len(seconds),
            "never_received": missed,
            "median_ms": round(1e3 * _pct(seconds, 50), 1) if seconds else None,
            "p95_ms": round(1e3 * _pct(seconds, 95), 1) if seconds else None,
            "max_ms": round(1e3 * max(seconds), 1) if seconds else None,
            "median_round_trips": round(_pct(trips, 50), 2) if trips else None,
            "max_round_trips": round(max(trips), 2) if trips else None,
            "within_two_round_trips": _rate(sum(1 for t in trips if t <= 2.0), len(trips)),
        }

    def agreement(self, drawn, min_frames=3, near_m=10.0):
        """Distances between devices' median drawn positions of each VO version: over all their
        frames, and over the frames that saw it from within near_m (a pose's rotation error
        moves a far VO's drawn position more)."""
        out = {}
        for name, limit in (("", None), ("near_", near_m)):
            gaps = []
            worst = None
            for (oid, version), per_device in drawn.items():
                medians = []
                for dev, views in per_device.items():
                    pts = [p for p, d in views if limit is None or d <= limit]
                    if len(pts) >= min_frames:
                        medians.append((dev, np.median(np.array(pts), axis=0), len(pts)))
                for i in range(len(medians)):
                    for j in range(i + 1, len(medians)):
                        gap = float(np.linalg.norm(medians[i][1] - medians[j][1]))
                        gaps.append(gap)
                        if worst is None or gap > worst["gap_m"]:
                            worst = {"id": oid, "version": version, "gap_m": round(gap, 4),
                                     "devices": [medians[i][0], medians[j][0]],
                                     "frames": [medians[i][2], medians[j][2]]}
            out[name + "worst"] = worst
            out[name + "pairs"] = len(gaps)
            out[name + "median_m"] = round(_pct(gaps, 50), 4) if gaps else None
            out[name + "max_m"] = round(max(gaps), 4) if gaps else None
        out["near_limit_m"] = near_m
        return out

    def detail(self):
        """Per object: owner, kind, versions, deleted, world position, how far it moved."""
        out = []
        for oid, states in sorted(self.timeline.by_id.items()):
            first, last = states[0], states[-1]
            out.append({
                "id": oid, "owner": first.owner,
                "kind": "line" if first.kind == VirtualObject.LINE else "anchor",
                "versions": last.version, "deleted": bool(last.deleted),
                "world_position": [round(float(x), 3)
                                   for x in self.world_points(first)[first.centre_index()]],
                "moved_m": round(float(np.linalg.norm(
                    self.sim.s * (last.position - first.position))), 3),
            })
        return out
