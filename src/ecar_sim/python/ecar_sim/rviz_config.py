"""rviz configurations for the devices that run: rviz/ecar.rviz shows the server's map, the
virtual objects and the cameras, and one `rviz/Image` display of ar_view per device; this module
writes a copy of it with one such display (and one dock entry) per device named, so that
`roslaunch launch/demo.launch devices:=device_0,device_2` shows those two and not others."""

import copy

import yaml


class RvizConfigError(ValueError):
    """The template or the device list cannot make a configuration (the message says why)."""


def device_names(devices):
    """Device names from a count ("3": device_0..device_2) or a comma-separated list."""
    text = str(devices).strip()
    if text.isdigit():
        n = int(text)
        if n < 1:
            raise RvizConfigError("devices: the count must be at least 1, not %d" % n)
        return ["device_%d" % i for i in range(n)]
    names = [name.strip() for name in text.split(",")]
    if not names or any(not name for name in names):
        raise RvizConfigError("devices: empty name in %r" % text)
    for name in names:
        if not all(c.isalnum() or c == "_" for c in name) or name[0].isdigit():
            raise RvizConfigError("devices: %r is not a ROS name" % name)
    if len(set(names)) != len(names):
        raise RvizConfigError("devices: a name appears twice in %r" % text)
    return names


def _is_ar_view(display):
    return (display.get("Class") == "rviz/Image" and
            str(display.get("Image Topic", "")).endswith("/ar_view"))


def for_devices(template, devices):
    """The configuration `template` (a parsed .rviz) with one ar_view display per device in
    `devices` (names), modelled on the template's first ar_view display."""
    try:
        manager = template["Visualization Manager"]
        displays = manager["Displays"]
    except (KeyError, TypeError):
        raise RvizConfigError("the template has no Visualization Manager/Displays")
    views = [d for d in displays if _is_ar_view(d)]
    if not views:
        raise RvizConfigError("the template has no rviz/Image display of an ar_view topic")
    config = copy.deepcopy(template)
    kept = [d for d in config["Visualization Manager"]["Displays"] if not _is_ar_view(d)]
    window = config.setdefault("Window Geometry", {})
    for display in views:
        window.pop(display.get("Name"), None)
    for name in devices:
        display = copy.deepcopy(views[0])
        display["Image Topic"] = "/%s/ar_view" % name
        display["Name"] = "%s ar_view" % name
        kept.append(display)
        window[display["Name"]] = {"collapsed": False}
    config["Visualization Manager"]["Displays"] = kept
    return config


def write(template_path, devices, out_path):
    """Reads the .rviz at template_path and writes the configuration for `devices` (a count or
    a comma-separated list) to out_path."""
    try:
        with open(template_path) as f:
            template = yaml.safe_load(f)
    except (OSError, yaml.YAMLError) as e:
        raise RvizConfigError("cannot read the rviz template %s: %s" % (template_path, e))
    config = for_devices(template, device_names(devices))
    with open(out_path, "w") as f:
        yaml.safe_dump(config, f, default_flow_style=False, sort_keys=False)
