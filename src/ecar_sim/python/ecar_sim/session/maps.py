"""The server map a session's poses are measured in.

The server keeps several maps (an atlas) and merges them when they overlap; every local graph
names its map (LocalGraph.map_id). A device whose map was merged into another has poses in two
coordinate systems: before the merge in its old map's, after it in the merged map's. The pose
metrics (device-vs-server, ATE, the map -> world fit of the VO and plane metrics) therefore use
each device's frames in the session's final map only, from its last switch into it on.
"""

import bisect
from collections import Counter


def final_map(records, devices):
    """The map most devices' last graph with a pose is in (None without any)."""
    server_maps = getattr(records, "server_maps", {})
    last = [maps[max(maps)] for maps in (server_maps.get(d, {}) for d in devices) if maps]
    return Counter(last).most_common(1)[0][0] if last else None


def last_map(records, device):
    """The map of the device's last graph with a pose (None without any)."""
    server_maps = getattr(records, "server_maps", {}).get(device, {})
    return server_maps[max(server_maps)] if server_maps else None


class FinalMapFrames:
    """Which frames of one device are in `final`:
    server(f)  its local graph of frame f is in the final map, on or after the switch;
    device(f)  the device's own pose of frame f is in the final map's coordinates, after the
               switch: the map the device names for that frame (DeviceFrame.map_id, its last
               graph's map when it tracked the frame) is the final map. For devices that did
               not name it (older recordings): the device's latest graph before frame f is in
               the final map (the device tracked the upload whose graph first named the final
               map in the old map's coordinates). Frames before the first graph count when the
               final map was the device's first. A device that left the final map (lost,
               relocalised into another) has its later poses in that other map's coordinates:
               they do not count.
    Records without map ids (older sessions) are one map: every frame counts."""

    def __init__(self, server_maps, final, device_maps=None):
        self.maps = sorted(set(server_maps.values()))
        self.switch, self.moved = None, False
        previous = None
        for f in sorted(server_maps):
            m = server_maps[f]
            if m == final and previous != final:
                self.switch, self.moved = f, previous is not None
            previous = m
        self.final = final
        self.server_maps = server_maps
        self.in_final = self.switch is not None
        self._frames = sorted(server_maps)
        self.device_maps = device_maps or {}

    def server(self, f):
        if not self.server_maps:
            return True
        return self.in_final and f >= self.switch and self.server_maps.get(f) == self.final

    def device(self, f):
        if not self.server_maps:
            return True
        if not self.in_final:
            return False
        if f <= self.switch:
            return not self.moved
        named = self.device_maps.get(f, 0)
        if named:
            return named == self.final
        latest = self._frames[bisect.bisect_left(self._frames, f) - 1]  # the last graph before f
        return self.server_maps[latest] == self.final

    def summary(self, server_frames):
        """The per-device summary fields: maps seen, the final map, from which frame on, and
        how many server poses were in other maps (left out of the pose metrics)."""
        return {"maps": self.maps, "final_map": self.final,
                "final_map_from_frame": self.switch,
                "server_poses_other_maps": sum(1 for f in server_frames if not self.server(f))}


def frames_of(records, device, final):
    """FinalMapFrames of `device` (records without server_maps: one map)."""
    frames = getattr(records, "device_frames", {}).get(device, {})
    return FinalMapFrames(getattr(records, "server_maps", {}).get(device, {}), final,
                          {f: getattr(e, "map_id", 0) for f, e in frames.items()})
