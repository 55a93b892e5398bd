"""What a dataset says is true, for the session metrics: the scene's free space (what a camera
can see through), a dataset's camera and its ground-truth poses.

    space = FreeSpace(yaml.safe_load(open("config/scenes/corridor.yaml")))
    space.line_of_sight(eye_w, p_w)
    camera = Camera.from_yaml(yaml.safe_load(open(DATASET + "/camera.yaml")))
    camera.in_view(p_c, max_range=40.0)
    T_w_c = read_groundtruth(DATASET)[frame]

Needs no running ROS (test/vo_metrics_test.py).
"""

import os

import numpy as np

from ecar_sim.alignment import quat_to_rot


class FreeSpace:
    """The scene's free space: the union of its `spaces` boxes minus its `solids`."""

    def __init__(self, scene):
        self.spaces = [(np.array(b["min"], float), np.array(b["max"], float))
                       for b in scene.get("spaces", [])]
        self.solids = [(np.array(b["min"], float), np.array(b["max"], float))
                       for b in scene.get("solids", []) or []]

    def free(self, points, margin=0.02):
        """Boolean per row of points (N x 3): inside a space (grown by margin) and in no solid
        (shrunk by margin)."""
        inside = np.zeros(len(points), bool)
        for lo, hi in self.spaces:
            inside |= np.all((points >= lo - margin) & (points <= hi + margin), axis=1)
        for lo, hi in self.solids:
            inside &= ~np.all((points > lo + margin) & (points < hi - margin), axis=1)
        return inside

    def line_of_sight(self, eye, target, step=0.05, end_gap=0.15):
        """True when the segment eye -> target stays in free space, its last end_gap metres
        (the surface the target lies on) excluded."""
        d = target - eye
        length = float(np.linalg.norm(d))
        if length <= end_gap:
            return True
        n = max(2, int((length - end_gap) / step))
        s = np.linspace(0.0, (length - end_gap) / length, n)
        return bool(self.free(eye + s[:, None] * d).all())


class Camera:
    """A pinhole camera (pixels) of a dataset's camera.yaml."""

    def __init__(self, fx, fy, cx, cy, width, height):
        self.fx, self.fy, self.cx, self.cy = fx, fy, cx, cy
        self.width, self.height = width, height

    @staticmethod
    def from_yaml(data):
        """The camera of a loaded camera.yaml (fx, fy, cx, cy, width, height)."""
        return Camera(float(data["fx"]), float(data["fy"]), float(data["cx"]), float(data["cy"]),
                      int(data["width"]), int(data["height"]))

    def in_view(self, p_c, max_range):
        """p_c: point in the optical frame (x right, y down, z forward)."""
        z = p_c[2]
        if z < 0.05 or np.linalg.norm(p_c) > max_range:
            return False
        u = self.fx * p_c[0] / z + self.cx
        v = self.fy * p_c[1] / z + self.cy
        return 0.0 <= u < self.width and 0.0 <= v < self.height


def read_groundtruth(folder):
    """{frame index: 4x4 T_world_camera} from a dataset's groundtruth.txt (TUM, one pose per
    frame, in frame order)."""
    poses = {}
    with open(os.path.join(folder, "groundtruth.txt")) as f:
        rows = [line.split() for line in f if line.strip() and not line.startswith("#")]
    for i, r in enumerate(rows):
        T = np.eye(4)
        T[:3, :3] = quat_to_rot([float(x) for x in r[4:8]])
        T[:3, 3] = [float(x) for x in r[1:4]]
        poses[i] = T
    return poses
