"""The hostile and malformed inputs a soak mixes in, one kind at a time in turn, each with the
rejection it must get. A kind returns (passed, outcome): passed when the server refused it with a
reason (a service's message, an InteractionResult's reason, or, for uploads, which get no answer,
the server's warning on /rosout when it is not throttled away) and nothing was accepted.

    h = Hostile(context)
    got = h.next()     # sends the next kind: (kind, passed, outcome) or None
    h.record(*got)     # into h.results[kind] (unless a fault hit it meanwhile)
    h.table()    # [(kind, what, sent, passed, an outcome)] for the report
"""

import collections
import os
import threading
import time

import rospy
from ecar_msgs.msg import Interaction, InteractionResult, Upload
from ecar_msgs.srv import Connect, ConnectRequest, Disconnect, LoadMap, SaveMap
from rosgraph_msgs.msg import Log

from ecar_sim.soak.editor import line

ANSWER_TIMEOUT_S = 10.0  # a service or an interaction must answer within this
WARN_WAIT_S = 2.5  # an upload's warning must appear on /rosout within this (unless throttled)
Context = collections.namedtuple(
    "Context", "editor devices map_dir database jpeg device_objects")


class RosoutWatch:
    """The server's warnings and errors on /rosout_agg, to find the one an input caused."""

    def __init__(self):
        self.lock = threading.Lock()
        self.lines = collections.deque(maxlen=500)  # (wall time, text)
        self.sub = rospy.Subscriber("/rosout_agg", Log, self.on_log, queue_size=500)

    def on_log(self, m):
        if m.level >= Log.WARN and m.name.startswith("/edge_server"):
            with self.lock:
                self.lines.append((time.time(), m.msg))

    def find(self, since, *words, timeout=WARN_WAIT_S):
        """The first warning after `since` holding every word, waiting up to timeout; or None."""
        end = time.time() + timeout
        while time.time() < end:
            with self.lock:
                for t, text in self.lines:
                    if t >= since and all(w in text for w in words):
                        return text
            time.sleep(0.1)
        return None


def _patched_size(jpeg, width, height):
    """The JPEG with the size in its first SOF marker replaced (a decompression bomb's header)."""
    data = bytearray(jpeg)
    i = 2
    while i + 9 < len(data):
        if data[i] != 0xFF:
            break
        marker, length = data[i + 1], (data[i + 2] << 8) | data[i + 3]
        if marker in (0xC0, 0xC1, 0xC2):
            data[i + 5:i + 7] = height.to_bytes(2, "big")
            data[i + 7:i + 9] = width.to_bytes(2, "big")
            return bytes(data)
        i += 2 + length
    raise ValueError("no SOF marker in the JPEG")


class Hostile:
    """See the module's docstring. ctx: Context (the editor, the devices' names, map_dir, the
    database's path, one valid JPEG of a device, device_objects() -> {id: version} of objects
    a device registered)."""

    def __init__(self, ctx):
        self.ctx = ctx
        self.rosout = RosoutWatch()
        self.results = collections.OrderedDict()  # kind -> [(passed, outcome)]
        self.kinds = [(name[len("kind_"):], getattr(self, name).__doc__.strip())
                      for name in sorted(dir(self)) if name.startswith("kind_")]
        self.turn = 0
        self.upload_pubs = {}
        self.connect = rospy.ServiceProxy("/ecar/connect", Connect)
        self.disconnect = rospy.ServiceProxy("/ecar/disconnect", Disconnect)
        self.load_map = rospy.ServiceProxy("/ecar/load_map", LoadMap)
        self.save_map = rospy.ServiceProxy("/ecar/save_map", SaveMap)

    def next(self):
        """Sends the next kind in turn; returns (kind, passed, outcome) for record(), or None
        when it was not sent (the server down or restarting, or the kind's preconditions not
        met yet, e.g. no device has registered an object)."""
        kind, _ = self.kinds[self.turn % len(self.kinds)]
        self.turn += 1
        try:
            passed, outcome = getattr(self, "kind_" + kind)()
        except (rospy.ServiceException, rospy.ROSException, OSError) as e:
            if "unavailable" in str(e) or "connect" in str(e).lower():
                return None
            passed, outcome = False, "no answer: %s" % e
        if passed is None:
            return None
        return kind, passed, outcome

    def record(self, kind, passed, outcome):
        self.results.setdefault(kind, []).append((passed, outcome))
        return kind, passed, outcome

    def table(self):
        """[(kind, what, sent, passed, a failing outcome or the first)] in kind order."""
        rows = []
        for kind, what in self.kinds:
            got = self.results.get(kind, [])
            failing = [o for p, o in got if not p]
            rows.append((kind, what, len(got), sum(1 for p, _ in got if p),
                         (failing or [o for _, o in got] or ["(not sent)"])[0]))
        return rows

    # ---- helpers

    def _upload(self, device, session, data, fmt="jpeg", device_id=None):
        pub = self.upload_pubs.get(device)
        if pub is None:
            pub = self.upload_pubs[device] = rospy.Publisher("/%s/upload" % device, Upload,
                                                             queue_size=5)
        end = time.time() + ANSWER_TIMEOUT_S  # the server's subscriber linked
        while pub.get_num_connections() == 0 and time.time() < end:
            time.sleep(0.05)
        m = Upload()
        m.header.stamp = rospy.Time.now()
        m.device_id = device if device_id is None else device_id
        m.session = session
        m.frame_index = 999999
        m.sent = rospy.Time.now()
        m.image.format = fmt
        m.image.data = data
        since = time.time()
        pub.publish(m)
        return since

    def _upload_outcome(self, since, *words):
        text = self.rosout.find(since, *words)
        return True, ("dropped: " + text) if text else \
            "dropped (no answer by design; the warning was throttled)"

    def _interact(self, m, topic=None):
        """Sends Interaction m (as the editor, or on another device's topic when given) and
        waits for its result; (passed, outcome) for an input that must be rejected."""
        got = self.ctx.editor.send_and_wait(m, ANSWER_TIMEOUT_S) if topic is None else \
            _one_result(topic, m)
        if got is None:
            return False, "no InteractionResult within %.0f s" % ANSWER_TIMEOUT_S
        return (not got.accepted), ("ACCEPTED (version %d)" % got.version if got.accepted
                                    else "rejected: " + got.reason)

    # ---- the kinds (their docstrings are the report's descriptions)

    def kind_burst_rate_limit(self):
        """300 interactions in 1.5 s from one device (over its rate limit)"""
        ed = self.ctx.editor
        if not ed.ready():
            return None, None
        since = time.time()
        # 200 a second against the server's 50 a second and burst of 100 (config/server.yaml
        # vo.max_interaction_rate, interaction_burst): at least 125 must be refused. Paced in
        # tens, not all at once: 300 at once overflowed the editor's publisher queue and the
        # server's subscriber queue (50 each) when the server was busy, and fewer than the burst
        # arrived (a soak failed so).
        for i in range(30):
            for _ in range(10):
                ed.send(Interaction.MANIPULATE, line(0.0, 0.0), 4000000000, 1)
            time.sleep(max(0.0, since + 0.05 * (i + 1) - time.time()))
        deadline = since + ANSWER_TIMEOUT_S
        while time.time() < deadline:
            limited = sum(n for reason, n in ed.ledger.rejected.items()
                          if "sent more than" in reason)
            if limited:
                return True, "rejected as rate-limited (%d so far in the run)" % limited
            time.sleep(0.2)
        return False, "no rejection for the rate limit"

    def kind_connect_bad_name(self):
        """connect with a name that is not a ROS name ('../x y')"""
        res = self.connect(ConnectRequest(device_id="../x y", camera_info=self.ctx.editor
                                          .camera_info))
        return (not res.accepted), ("ACCEPTED" if res.accepted else "refused: " + res.message)

    def kind_connect_huge_camera(self):
        """connect with a 100000 x 100000 camera"""
        info = type(self.ctx.editor.camera_info)()
        info.width = info.height = 100000
        info.K = [50000.0, 0, 50000.0, 0, 50000.0, 50000.0, 0, 0, 1]
        res = self.connect(ConnectRequest(device_id="soak_huge", camera_info=info))
        return (not res.accepted), ("ACCEPTED" if res.accepted else "refused: " + res.message)

    def kind_connect_reserved(self):
        """connect as a reserved name ('rviz')"""
        res = self.connect(ConnectRequest(device_id="rviz", camera_info=self.ctx.editor
                                          .camera_info))
        return (not res.accepted), ("ACCEPTED" if res.accepted else "refused: " + res.message)

    def kind_connect_takeover(self):
        """connect as a live device without its token (taking its name)"""
        res = self.connect(ConnectRequest(device_id=self.ctx.devices[0],
                                          camera_info=self.ctx.editor.camera_info,
                                          session=0x5EED))
        return (not res.accepted), ("ACCEPTED" if res.accepted else "refused: " + res.message)

    def kind_delete_others_object(self):
        """delete another device's object (vo.policy owner_delete)"""
        objects = self.ctx.device_objects()
        if not objects or not self.ctx.editor.ready():
            return None, None
        object_id, version = sorted(objects.items())[-1]
        ed = self.ctx.editor
        return self._interact(ed.interaction(Interaction.DELETE, line(0, 0), object_id, version))

    def kind_delete_without_version(self):
        """delete with base_version 0 (an unconditional delete)"""
        ed = self.ctx.editor
        with ed.lock:
            own = sorted(ed.live)
        if not own or not ed.ready():
            return None, None
        return self._interact(ed.interaction(Interaction.DELETE, line(0, 0), own[0], 0))

    def kind_disconnect_foreign(self):
        """disconnect a live device with a wrong token"""
        res = self.disconnect(device_id=self.ctx.devices[0], session=0x5EED)
        return (not res.ok), ("ACCEPTED: " + res.message if res.ok else "refused: " + res.message)

    def kind_interaction_impersonated(self):
        """an interaction on another device's topic with a wrong token"""
        ed = self.ctx.editor
        if not ed.ready():  # the server is up and answering
            return None, None
        m = ed.interaction(Interaction.REGISTER, line(0.2, 0.2), session=0x5EED)
        m.device_id = self.ctx.devices[0]
        m.request_id = 4000000000 + self.turn  # not one of the device's own
        return self._interact(m, topic="/%s" % self.ctx.devices[0])

    def kind_interaction_nan(self):
        """a registration with NaN coordinates"""
        ed = self.ctx.editor
        if not ed.ready():
            return None, None
        return self._interact(ed.interaction(Interaction.REGISTER,
                                             line(float("nan"), 0.0)))

    def kind_interaction_huge_line(self):
        """a registration of a 1e6 m line"""
        ed = self.ctx.editor
        if not ed.ready():
            return None, None
        return self._interact(ed.interaction(Interaction.REGISTER, line(0.0, 0.0, length=1e6)))

    def kind_interaction_unknown_id(self):
        """a change of an object id that does not exist"""
        ed = self.ctx.editor
        if not ed.ready():
            return None, None
        return self._interact(ed.interaction(Interaction.MANIPULATE, line(0.0, 0.0),
                                             3999999999, 1))

    def kind_interaction_wrong_session(self):
        """an interaction with a wrong session token on the sender's own topic"""
        ed = self.ctx.editor
        if not ed.ready():
            return None, None
        return self._interact(ed.interaction(Interaction.REGISTER, line(0.1, 0.1),
                                             session=ed.session ^ 0xFFFF))

    def kind_load_map_corrupt(self):
        """load_map of a file of random bytes named like a map"""
        path = os.path.join(self.ctx.map_dir, "junk.ecarmap")
        with open(path, "wb") as f:
            f.write(os.urandom(4096))
        res = self.load_map(path="junk.ecarmap")
        return (not res.success), ("ACCEPTED: " + res.message if res.success
                                   else "refused: " + res.message)

    def kind_load_map_escape(self):
        """load_map of a path outside map_dir ('../../etc/passwd')"""
        res = self.load_map(path="../../etc/passwd")
        return (not res.success), ("ACCEPTED: " + res.message if res.success
                                   else "refused: " + res.message)

    def kind_load_map_fifo(self):
        """load_map of a FIFO in map_dir (would block a reader for ever)"""
        path = os.path.join(self.ctx.map_dir, "trap.ecarmap")
        if not os.path.exists(path):
            os.mkfifo(path)
        start = time.time()
        res = self.load_map(path="trap.ecarmap")
        took = time.time() - start
        passed = not res.success and took < ANSWER_TIMEOUT_S
        return passed, ("ACCEPTED: " if res.success else "refused in %.2f s: " % took) + \
            res.message

    def kind_load_map_symlink(self):
        """load_map of a link in map_dir to the VO database"""
        path = os.path.join(self.ctx.map_dir, "link.ecarmap")
        if not os.path.lexists(path):
            os.symlink(self.ctx.database, path)
        res = self.load_map(path="link.ecarmap")
        return (not res.success), ("ACCEPTED: " + res.message if res.success
                                   else "refused: " + res.message)

    def kind_save_map_over_database(self):
        """save_map over the VO database's path"""
        res = self.save_map(path=self.ctx.database)
        return (not res.success), ("ACCEPTED: " + res.message if res.success
                                   else "refused: " + res.message)

    def kind_upload_corrupt_jpeg(self):
        """an upload whose JPEG is random bytes"""
        ed = self.ctx.editor
        if not ed.ready():
            return None, None
        data = b"\xff\xd8\xff\xe0" + os.urandom(20000)
        return self._upload_outcome(self._upload(ed.name, ed.session, data), ed.name, "dropped")

    def kind_upload_jpeg_bomb(self):
        """an upload whose JPEG header claims 65000 x 65000 pixels (a decompression bomb)"""
        ed = self.ctx.editor
        if not ed.ready():
            return None, None
        data = _patched_size(self.ctx.jpeg, 65000, 65000)
        return self._upload_outcome(self._upload(ed.name, ed.session, data), ed.name, "dropped")

    def kind_upload_oversized(self):
        """an upload of 3 MB (over max_upload_bytes)"""
        ed = self.ctx.editor
        if not ed.ready():
            return None, None
        return self._upload_outcome(self._upload(ed.name, ed.session, os.urandom(3000000)),
                                    ed.name, "max_upload_bytes")

    def kind_upload_png(self):
        """an upload whose format says png (only JPEG is decoded)"""
        ed = self.ctx.editor
        if not ed.ready():
            return None, None
        since = self._upload(ed.name, ed.session, self.ctx.jpeg, fmt="png")
        return self._upload_outcome(since, ed.name, "dropped")

    def kind_upload_spoofed(self):
        """another device's upload topic with a wrong token (a valid JPEG)"""
        device = self.ctx.devices[-1]
        since = self._upload(device, 0x5EED, self.ctx.jpeg)
        return self._upload_outcome(since, device, "session")

    def kind_upload_wrong_device_id(self):
        """an upload naming another device than its topic's"""
        ed = self.ctx.editor
        if not ed.ready():
            return None, None
        since = self._upload(ed.name, ed.session, self.ctx.jpeg, device_id=self.ctx.devices[0])
        return self._upload_outcome(since, ed.name, "device_id")


def _one_result(namespace, m):
    """Publishes Interaction m on <namespace>/interaction and waits for the result with its
    request id on <namespace>/interaction_result (None on timeout)."""
    box, ev = [], threading.Event()

    def cb(msg):
        if msg.request_id == m.request_id:
            box.append(msg)
            ev.set()
    sub = rospy.Subscriber(namespace + "/interaction_result", InteractionResult, cb,
                           queue_size=50)
    pub = rospy.Publisher(namespace + "/interaction", Interaction, queue_size=5)
    end = time.time() + ANSWER_TIMEOUT_S  # both ends linked to the server
    while (pub.get_num_connections() == 0 or sub.get_num_connections() == 0) and \
            time.time() < end:
        time.sleep(0.05)
    pub.publish(m)
    ev.wait(ANSWER_TIMEOUT_S)
    sub.unregister()
    pub.unregister()
    return box[0] if box else None
