#!/usr/bin/python3
"""Tests of ecar_sim.rviz_config on the repository's rviz/ecar.rviz: one ar_view display per
device named, everything else kept, bad device lists and templates rejected with a reason."""

import os
import sys
import tempfile
import unittest

import yaml

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))
from ecar_sim.rviz_config import (RvizConfigError, device_names, for_devices,  # noqa: E402
                                  write)

TEMPLATE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "..", "rviz",
                        "ecar.rviz")


def load_template():
    with open(TEMPLATE) as f:
        return yaml.safe_load(f)


def image_topics(config):
    return [d["Image Topic"] for d in config["Visualization Manager"]["Displays"]
            if d["Class"] == "rviz/Image"]


class DeviceNamesTest(unittest.TestCase):
    def test_count_and_list(self):
        self.assertEqual(device_names("3"), ["device_0", "device_1", "device_2"])
        self.assertEqual(device_names(" device_0, device_2"), ["device_0", "device_2"])
        self.assertEqual(device_names("phone"), ["phone"])

    def test_bad_lists(self):
        for bad in ("0", "", "device_0,,device_1", "a b", "device_0,device_0", "2x", "a/b"):
            with self.assertRaises(RvizConfigError, msg=bad):
                device_names(bad)


class ForDevicesTest(unittest.TestCase):
    def test_one_ar_view_per_device(self):
        template = load_template()
        config = for_devices(template, ["device_0", "device_2", "device_5"])
        self.assertEqual(image_topics(config),
                         ["/device_0/ar_view", "/device_2/ar_view", "/device_5/ar_view"])
        names = [d["Name"] for d in config["Visualization Manager"]["Displays"]]
        self.assertIn("device_5 ar_view", names)
        self.assertIn("device_5 ar_view", config["Window Geometry"])
        self.assertNotIn("device_1 ar_view", config["Window Geometry"])
        # The other displays, in their order, and the template itself, untouched.
        others = [d for d in template["Visualization Manager"]["Displays"]
                  if d["Class"] != "rviz/Image"]
        self.assertEqual(config["Visualization Manager"]["Displays"][:len(others)], others)
        self.assertEqual(image_topics(template), ["/device_0/ar_view", "/device_1/ar_view"])

    def test_template_without_ar_view(self):
        template = load_template()
        displays = template["Visualization Manager"]["Displays"]
        template["Visualization Manager"]["Displays"] = [
            d for d in displays if d["Class"] != "rviz/Image"]
        with self.assertRaisesRegex(RvizConfigError, "ar_view"):
            for_devices(template, ["device_0"])
        with self.assertRaisesRegex(RvizConfigError, "Visualization Manager"):
            for_devices({"Panels": []}, ["device_0"])

    def test_write_round_trip_and_unreadable_template(self):
        with tempfile.TemporaryDirectory() as d:
            out = os.path.join(d, "x.rviz")
            write(TEMPLATE, "device_0,device_2", out)
            with open(out) as f:
                self.assertEqual(image_topics(yaml.safe_load(f)),
                                 ["/device_0/ar_view", "/device_2/ar_view"])
            broken = os.path.join(d, "broken.rviz")
            with open(broken, "w") as f:
                f.write("Visualization Manager: [unclosed\n")
            with self.assertRaisesRegex(RvizConfigError, "broken.rviz"):
                write(broken, "1", out)
            with self.assertRaisesRegex(RvizConfigError, "missing.rviz"):
                write(os.path.join(d, "missing.rviz"), "1", out)


if __name__ == "__main__":
    import rosunit
    rosunit.unitrun("ecar_sim", "rviz_config", "__main__")
