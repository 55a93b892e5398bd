"""The server's planes checked against the scene's surfaces (the `planes` of a session summary).

Each plane the devices received (map frame) is put into the dataset world with the
map -> world similarity of the session (see `alignment.robust_similarity`) and matched to the
nearest parallel face of the scene's boxes: is its label (ecar_msgs/Plane FLOOR, WALL, ...)
right, how far is it from that face, at what angle, and does it lie on it (within
`max_distance_m`: a plane labelled right but 10 cm above the floor, a "second floor", is
counted as off its surface, not hidden among the right ones). Needs no running ROS
(test/vo_metrics_test.py).
"""

import math

import numpy as np
from ecar_msgs.msg import Plane

PLANE_LABELS = {Plane.FLOOR: "floor", Plane.WALL: "wall", Plane.CEILING: "ceiling",
                Plane.OTHER: "other"}


def scene_faces(scene):
    """The faces of the scene's boxes: (label, unit normal, point). Bottom faces of `spaces`
    are floor, top faces ceiling, side faces walls; faces of `solids` are labelled by their
    orientation with an "object " prefix (their top is not the floor)."""
    faces = []
    for key, prefix in (("spaces", ""), ("solids", "object ")):
        for box in scene.get(key, []) or []:
            lo, hi = np.array(box["min"], float), np.array(box["max"], float)
            for axis in range(3):
                for value in (lo[axis], hi[axis]):
                    n = np.zeros(3)
                    n[axis] = 1.0
                    p = (lo + hi) / 2.0
                    p[axis] = value
                    if axis == 2:
                        label = "floor" if value == lo[2] else "ceiling"
                        if prefix:
                            label = "top" if value == hi[2] else "bottom"
                    else:
                        label = "wall"
                    faces.append((prefix + label, n, p))
    return faces


def check_planes(planes, scene, sim, max_angle_deg=10.0, max_distance_m=0.05):
    """Each server plane (dicts: id, label, normal, offset, centroid, points; map frame) put
    into the world and matched to the nearest parallel scene face: is its label right, how far
    is it from the face, at what angle. `on_surface` counts the planes labelled right within
    max_distance_m of their face; `off_surface` lists the ids of the others labelled right."""
    faces = scene_faces(scene)
    rows = []
    for pl in sorted(planes, key=lambda p: p["id"]):
        n = sim.r @ np.asarray(pl["normal"], float)
        n /= np.linalg.norm(n)
        c = sim.apply(pl["centroid"])
        best = None
        for label, fn, fp in faces:
            cos = abs(float(n @ fn))
            if cos < math.cos(math.radians(max_angle_deg)):
                continue
            dist = abs(float(fn @ (c - fp)))
            if best is None or dist < best[1]:
                best = (label, dist, math.degrees(math.acos(min(1.0, cos))))
        label = PLANE_LABELS.get(pl["label"], "other")
        truth = best[0] if best else "none"
        # A solid's top is a horizontal surface below the camera (floor by the gravity rule, or
        # other), its sides are walls (or other).
        accepted = {"object top": ("floor", "other"), "object wall": ("wall", "other"),
                    "object bottom": ("ceiling", "other")}.get(truth, (truth,))
        right = label in accepted
        on_surface = right and best is not None and best[1] <= max_distance_m
        rows.append({"id": pl["id"], "label": label, "true_surface": truth, "right": right,
                     "on_surface": on_surface,
                     "points": pl["points"],
                     "distance_m": round(best[1], 4) if best else None,
                     "angle_deg": round(best[2], 2) if best else None})
    return {"planes": len(rows), "labelled_right": sum(1 for r in rows if r["right"]),
            "on_surface": sum(1 for r in rows if r["on_surface"]),
            "off_surface": [r["id"] for r in rows if r["right"] and not r["on_surface"]],
            "max_distance_m": max_distance_m,
            "found": sorted({r["true_surface"] for r in rows if r["right"]}), "detail": rows}
