"""The VO and plane parts of a session summary, and the raw records they are computed from.

The server's map has its own origin and scale: the similarity map -> world is fitted to the
server's camera positions and the ground truth (alignment.robust_similarity), then
vo_metrics measures VO sync and plane_metrics checks the planes in the world. save_raw keeps
what those read in DIR/vo_raw.json.gz; RawCollector reads it back for --reevaluate.
"""

import gzip
import json
import os
from types import SimpleNamespace

import numpy as np
import yaml

from ecar_sim import ground_truth as truth
from ecar_sim import plane_metrics
from ecar_sim import vo_metrics as vm
from ecar_sim.alignment import robust_similarity
from ecar_sim.session import maps
from ecar_sim.session.collecting import FrameRecord
from ecar_sim.session.evaluating import rnd
from ecar_sim.session.report import log


def fit_map_to_world(devices, datasets, records):
    """(Similarity T_world_map, a description of the fit) from the server's camera positions
    and the ground truth, in the session's final map (session.maps). Poses far off the fit are
    dropped as outliers by a second fit. Raises ValueError without poses."""
    src, dst = [], []
    final = maps.final_map(records, devices)
    for d in devices:
        gt = truth.read_groundtruth(datasets[d])
        in_final = maps.frames_of(records, d, final)
        for f, (p, _) in records.server_poses[d].items():
            if f in gt and in_final.server(f):
                src.append(p)
                dst.append(gt[f][:3, 3])
    sim, keep, residual = robust_similarity(np.array(src), np.array(dst))
    info = {"scale": rnd(float(sim.s), 5), "poses": int(keep.sum()),
            "poses_dropped": int((~keep).sum()),
            "rmse_m": rnd(float(np.sqrt(np.mean(residual ** 2))), 4)}
    return sim, info


def _read_scene(path):
    with open(path) as f:
        return yaml.safe_load(f)


def evaluate_vos(args, devices, datasets, records, map_to_world):
    """VO sync success, latency and agreement (ecar_sim.vo_metrics), or None without VOs."""
    if not records.objects or map_to_world is None:
        return None
    scene = _read_scene(args.scene)
    device_records = []
    final = maps.final_map(records, devices)
    for d in devices:
        with open(os.path.join(datasets[d], "camera.yaml")) as f:
            camera = truth.Camera.from_yaml(yaml.safe_load(f))
        # Frames in the final map only: before its map merged a device sees another map's
        # objects (not those of the final map) in another map's coordinates.
        in_final = maps.frames_of(records, d, final)
        frames = {f: (e.wall, e.status, e.position, e.orientation, e.held, e.received or {})
                  for f, e in records.device_frames.get(d, {}).items() if in_final.device(f)}
        device_records.append(vm.DeviceRecord(d, camera, frames,
                                              truth.read_groundtruth(datasets[d]),
                                              records.graph_walls[d]))
    states = [vm.VoState(m.id, m.version, m.deleted, m.owner, m.kind,
                         (m.position.x, m.position.y, m.position.z),
                         (m.start.x, m.start.y, m.start.z), (m.end.x, m.end.y, m.end.z), wall)
              for wall, m in records.objects]
    sim, info = map_to_world
    result = vm.VoEvaluator(vm.Timeline(states), device_records, truth.FreeSpace(scene), sim,
                            args.vo_range).evaluate()
    result["map_to_world"] = info
    result["interaction_results"] = records.results
    return result


def evaluate_planes(args, devices, records, map_to_world):
    """The server's planes in the session's final map (as the devices received them) against
    the scene's surfaces, or None without planes. A plane last received in another map (a
    device's map before it merged, which the device dropped with that map) is counted apart:
    its coordinates are not the final map's. Records without map ids are one map."""
    if not records.planes or map_to_world is None:
        return None
    final = maps.final_map(records, devices)
    in_final = [p for p in records.planes.values() if not p.get("map") or p["map"] == final]
    result = plane_metrics.check_planes(in_final, _read_scene(args.scene), map_to_world[0])
    result["other_maps"] = len(records.planes) - len(in_final)
    result["removed"] = len(getattr(records, "removed_planes", ()))
    return result


def evaluate_structure(args, devices, datasets, records):
    """(vo, planes) of the summary, each None when there is nothing to measure."""
    try:
        fit = fit_map_to_world(devices, datasets, records)
    except ValueError as e:
        log("VO and plane metrics skipped: no map -> world fit (%s)" % e)
        fit = None
    return (evaluate_vos(args, devices, datasets, records, fit),
            evaluate_planes(args, devices, records, fit))


def save_raw(path, records):
    """What the VO and plane metrics read, so that --reevaluate can recompute them."""

    def point(p):
        return [p.x, p.y, p.z]

    raw = {
        "device_frames": {d: {str(f): [e.status, e.position, e.orientation, e.wall, e.held,
                                       e.received or {}, e.map_id]
                              for f, e in fr.items()}
                          for d, fr in records.device_frames.items()},
        "server_poses": {d: {str(f): [p, q] for f, (p, q) in sp.items()}
                         for d, sp in records.server_poses.items()},
        "server_maps": {d: {str(f): m for f, m in sm.items()}
                        for d, sm in records.server_maps.items()},
        "graph_walls": records.graph_walls,
        "objects": [[w, {"id": m.id, "version": m.version, "deleted": m.deleted, "owner": m.owner,
                         "kind": m.kind, "position": point(m.position), "start": point(m.start),
                         "end": point(m.end)}] for w, m in records.objects],
        "results": records.results,
        "planes": list(records.planes.values()),
        "removed_planes": sorted(records.removed_planes),
    }
    with gzip.open(path, "wt") as f:
        json.dump(raw, f)


class RawCollector:
    """A Collector's records read back from save_raw's file (uploaded and tracking_time of
    the device frames are not kept: False and 0.0)."""

    def __init__(self, path):
        with gzip.open(path, "rt") as f:
            raw = json.load(f)
        self.device_frames = {
            d: {int(f): FrameRecord(e[0], tuple(e[1]), tuple(e[2]), False, 0.0, e[3],
                                    {int(k): v for k, v in e[4].items()},
                                    {int(k): v for k, v in (e[5] if len(e) > 5 else {}).items()},
                                    e[6] if len(e) > 6 else 0)
                for f, e in fr.items()}
            for d, fr in raw["device_frames"].items()}
        self.server_poses = {d: {int(f): (tuple(p), tuple(q)) for f, (p, q) in sp.items()}
                             for d, sp in raw["server_poses"].items()}
        # Sessions recorded before the atlas have no map ids: one map.
        self.server_maps = {d: {int(f): m for f, m in sm.items()}
                            for d, sm in raw.get("server_maps", {}).items()}
        self.graph_walls = raw["graph_walls"]

        def pt(v):
            return SimpleNamespace(x=v[0], y=v[1], z=v[2])

        self.objects = [(w, SimpleNamespace(id=o["id"], version=o["version"],
                                            deleted=o["deleted"], owner=o["owner"],
                                            kind=o["kind"], position=pt(o["position"]),
                                            start=pt(o["start"]), end=pt(o["end"])))
                        for w, o in raw["objects"]]
        self.results = raw["results"]
        self.planes = {p["id"]: p for p in raw["planes"]}
        self.removed_planes = set(raw.get("removed_planes", []))
