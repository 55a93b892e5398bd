#!/usr/bin/python3
"""Tests of the one Umeyama fit of the Python tools (python/ecar_sim/alignment.py) against
known transforms: a similarity, a rigid motion, outliers, quaternions both ways."""

import math
import os
import sys
import unittest

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))
from ecar_sim.alignment import (Similarity, quat_to_rot, robust_similarity,  # noqa: E402
                                rot_to_quat, umeyama)

Q = (0.1, -0.3, 0.2, 0.9)  # not normalised on purpose
T = np.array([1.0, -2.0, 0.5])


def points(n=20, seed=3):
    return np.random.default_rng(seed).normal(size=(n, 3))


class UmeyamaTest(unittest.TestCase):
    def test_recovers_a_known_similarity(self):
        src = points()
        r = quat_to_rot(Q)
        dst = 2.5 * src @ r.T + T
        s, r_est, t = umeyama(src, dst)
        self.assertAlmostEqual(s, 2.5, places=9)
        np.testing.assert_allclose(r_est, r, atol=1e-9)
        np.testing.assert_allclose(t, T, atol=1e-9)

    def test_rigid_fit_has_unit_scale(self):
        src = points()
        r = quat_to_rot(Q)
        dst = src @ r.T + T
        s, r_est, t = umeyama(src, dst, with_scale=False)
        self.assertEqual(s, 1.0)
        np.testing.assert_allclose(r_est, r, atol=1e-9)
        np.testing.assert_allclose(t, T, atol=1e-9)

    def test_rigid_fit_of_scaled_points_keeps_unit_scale(self):
        # Scaled data: the SE(3) fit still returns s = 1 and the right rotation; its
        # translation is the one that matches the centroids.
        src = points()
        r = quat_to_rot(Q)
        dst = 2.0 * src @ r.T + T
        s, r_est, t = umeyama(src, dst, with_scale=False)
        self.assertEqual(s, 1.0)
        np.testing.assert_allclose(r_est, r, atol=1e-9)
        np.testing.assert_allclose(t, dst.mean(0) - r @ src.mean(0), atol=1e-9)

    def test_a_mirror_image_gives_a_proper_rotation(self):
        src = points()
        dst = src * [1.0, 1.0, -1.0]
        _, r, _ = umeyama(src, dst)
        self.assertAlmostEqual(np.linalg.det(r), 1.0, places=9)

    def test_bad_input(self):
        with self.assertRaises(ValueError):
            umeyama([[0, 0, 0], [1, 0, 0]], [[0, 0, 0], [1, 0, 0]])  # fewer than 3
        with self.assertRaises(ValueError):
            umeyama(points(4), points(5))  # counts differ
        with self.assertRaises(ValueError):
            umeyama(np.ones((4, 3)), points(4))  # the source does not spread: no scale


class SimilarityTest(unittest.TestCase):
    def test_apply_to_a_point_and_to_rows(self):
        sim = Similarity(2.0, quat_to_rot((0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4))),
                         T)
        np.testing.assert_allclose(sim.apply([1.0, 0.0, 0.0]), T + [0.0, 2.0, 0.0], atol=1e-12)
        rows = sim.apply([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
        np.testing.assert_allclose(rows, [T + [0.0, 2.0, 0.0], T + [-2.0, 0.0, 0.0]], atol=1e-12)

    def test_robust_fit_drops_outliers(self):
        src = points(30)
        r = quat_to_rot(Q)
        dst = 0.5 * src @ r.T + T
        dst[:3] += [5.0, 0.0, 0.0]  # three poses from another map
        sim, keep, residual = robust_similarity(src, dst)
        self.assertEqual(keep.tolist(), [False] * 3 + [True] * 27)
        self.assertAlmostEqual(sim.s, 0.5, places=9)
        np.testing.assert_allclose(sim.r, r, atol=1e-9)
        self.assertLess(float(residual.max()), 1e-9)


class QuaternionTest(unittest.TestCase):
    def test_round_trip(self):
        for q in (Q, (0.0, 0.0, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0), (0.3, 0.4, -0.5, 0.1)):
            n = math.sqrt(sum(x * x for x in q))
            q_back = rot_to_quat(quat_to_rot(q))
            sign = 1.0 if q[3] >= 0 else -1.0
            np.testing.assert_allclose(q_back, [sign * x / n for x in q], atol=1e-9)

    def test_rotation_about_z(self):
        r = quat_to_rot((0.0, 0.0, math.sin(math.pi / 6), math.cos(math.pi / 6)))  # 60 deg
        np.testing.assert_allclose(r @ [1.0, 0.0, 0.0], [0.5, math.sqrt(3) / 2, 0.0], atol=1e-12)


if __name__ == "__main__":
    import rosunit
    rosunit.unitrun("ecar_sim", "alignment", "__main__")
