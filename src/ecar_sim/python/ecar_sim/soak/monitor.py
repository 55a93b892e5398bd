"""What the soak watches on every device: when its last aligned local graph came (OK or
RELOCALISED, read from the message's first fields without deserialising the whole graph) and
every InteractionResult it got (into the ledger, with the objects each device registered, for
the hostile inputs that target another device's object).

    mon = Monitor(["device_0", "device_1"], ledger)
    mon.first_aligned_after("device_0", t)   # wall time of its first aligned graph after t
"""

import struct
import threading
import time

import rospy
from ecar_msgs.msg import InteractionResult, LocalGraph

ALIGNED = (LocalGraph.OK, LocalGraph.RELOCALISED)


def graph_status(buff):
    """(device_id, frame_index, status, map_epoch) of a serialised ecar_msgs/LocalGraph."""
    (n,) = struct.unpack_from("<I", buff, 12)  # header: seq, stamp (2 x u32), frame_id
    i = 16 + n
    (n,) = struct.unpack_from("<I", buff, i)
    device = bytes(buff[i + 4:i + 4 + n]).decode("utf-8", "replace")
    i += 4 + n
    frame, status = struct.unpack_from("<IB", buff, i)
    (epoch,) = struct.unpack_from("<I", buff, i + 5 + 56)  # after the pose (7 float64)
    return device, frame, status, epoch


class Monitor:
    """See the module's docstring."""

    def __init__(self, devices, ledger):
        self.lock = threading.Lock()
        self.ledger = ledger
        self.aligned = {d: [] for d in devices}  # (wall time, frame) of aligned graphs, bounded
        self.graphs = {d: 0 for d in devices}
        self.registered = {}  # object id -> version, of the devices' accepted results
        self.subs = []
        for d in devices:
            self.subs.append(rospy.Subscriber("/%s/local_graph" % d, rospy.AnyMsg,
                                              self._graph_cb(d), queue_size=20))
            self.subs.append(rospy.Subscriber("/%s/interaction_result" % d, InteractionResult,
                                              self._result_cb(d), queue_size=200))

    def _graph_cb(self, device):
        def cb(msg):
            try:
                _, frame, status, _ = graph_status(msg._buff)
            except (struct.error, IndexError):
                return
            with self.lock:
                self.graphs[device] += 1
                if status in ALIGNED:
                    times = self.aligned[device]
                    times.append((time.time(), frame))
                    if len(times) > 4000:
                        del times[:2000]
        return cb

    def _result_cb(self, device):
        def cb(msg):
            self.ledger.on_result(device, msg)
            if msg.accepted:
                with self.lock:
                    self.registered[msg.object_id] = msg.version
        return cb

    def first_aligned_after(self, device, t, below=None):
        """Wall time of the device's first aligned graph after t (with a frame number below
        `below` when given: a restarted device numbers its frames from its dataset's start
        again, so a graph answering an upload of the killed process does not count), or None."""
        with self.lock:
            return next((a for a, f in self.aligned[device]
                         if a > t and (below is None or f < below)), None)

    def last_frame(self, device):
        """The frame number of the device's last aligned graph (None before the first)."""
        with self.lock:
            return self.aligned[device][-1][1] if self.aligned[device] else None

    def device_objects(self):
        """{object id: newest acknowledged version} of the devices' own changes."""
        with self.lock:
            return dict(self.registered)
