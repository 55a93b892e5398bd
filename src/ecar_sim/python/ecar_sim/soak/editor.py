"""The soak's own VO client, as a user editing objects all the time: it connects as a device
(soak_editor; it uploads nothing, so it connects again every KEEPALIVE_S with its token to stay
registered), registers short lines near the map's origin, moves them and deletes the oldest,
keeping at most MAX_LIVE of its own. Every answer goes to the ledger; its deletes are marked as
such. After a server restart its token is unknown: the next connect gets a new one.

    editor = VoEditor(camera_info, ledger, random.Random(1))
    editor.step()   # at --editor-rate: keep-alive and one change
"""

import threading
import time

import rospy
from ecar_msgs.msg import Interaction, InteractionResult, VirtualObject
from ecar_msgs.srv import Connect, ConnectRequest

NAME = "soak_editor"
KEEPALIVE_S = 3.0  # well under the server's device_timeout (10 s)
MAX_LIVE = 20
CONNECT_SERVICE = "/ecar/connect"


def line(x, y, z=0.0, length=0.1):
    """A LINE VirtualObject from (x, y, z) along +x, 2 cm wide, normal +z (map frame)."""
    o = VirtualObject()
    o.kind = VirtualObject.LINE
    o.start.x, o.start.y, o.start.z = x, y, z
    o.end.x, o.end.y, o.end.z = x + length, y, z
    o.position.x, o.position.y, o.position.z = x + length / 2, y, z
    o.r, o.g, o.b = 250, 120, 0
    o.width = 0.02
    o.normal.z = 1.0
    return o


class VoEditor:
    """See the module's docstring. Thread-safe: results arrive on rospy's threads."""

    def __init__(self, camera_info, ledger, rng, name=NAME):
        self.name = name
        self.camera_info = camera_info
        self.ledger = ledger
        self.rng = rng
        self.session = 0
        self.connected_at = 0.0
        self.connects = 0  # accepted connects that got a new token
        self.answered_since_connect = False  # the server's topics reach us in this session
        self.lock = threading.Lock()
        self.live = {}  # own object id -> version
        self.pending = {}  # request id -> (type, object id, session it was sent with)
        self.awaited = {}  # request id -> its result once in (send_and_wait), or None
        self.answered = threading.Condition(self.lock)
        self.next_request = 1
        self.pub = rospy.Publisher("/%s/interaction" % name, Interaction, queue_size=50)
        self.sub = rospy.Subscriber("/%s/interaction_result" % name, InteractionResult,
                                    self.on_result, queue_size=200)
        self._connect = rospy.ServiceProxy(CONNECT_SERVICE, Connect)

    def keep_alive(self):
        """Connects (again) when KEEPALIVE_S have passed; True while registered."""
        now = time.time()
        if self.session and now - self.connected_at < KEEPALIVE_S:
            return True
        try:
            res = self._connect(ConnectRequest(device_id=self.name, camera_info=self.camera_info,
                                               session=self.session))
        except (rospy.ServiceException, rospy.ROSException, OSError):
            self.session = 0  # the server is down: a new token next time
            return False
        if not res.accepted:
            self.session = 0
            return False
        if res.session != self.session:
            self.connects += 1
            self.answered_since_connect = False
        self.session, self.connected_at = res.session, now
        return True

    def ready(self):
        """Connected, and an answer came since: a message to the server arrives (just after a
        connect the server's subscriber to our topic may not be linked yet)."""
        return bool(self.session) and self.answered_since_connect

    def step(self):
        """One change (register, move or delete one of its objects) after the keep-alive."""
        if not self.keep_alive():
            return
        with self.lock:
            live = sorted(self.live.items())
        r = self.rng.random()
        if not live or (len(live) < MAX_LIVE and r < 0.45):
            self.send(Interaction.REGISTER, line(self.rng.uniform(-1.0, 1.0),
                                                 self.rng.uniform(-1.0, 1.0)))
        elif r < 0.8 or len(live) < MAX_LIVE // 2:
            object_id, version = self.rng.choice(live)
            self.send(Interaction.MANIPULATE, line(self.rng.uniform(-1.0, 1.0),
                                                   self.rng.uniform(-1.0, 1.0)),
                      object_id, version)
        else:
            object_id, version = live[0]
            self.send(Interaction.DELETE, VirtualObject(), object_id, version)

    def interaction(self, type_, obj, object_id=0, base_version=0, session=None):
        """An Interaction of this client with the next request id (not sent)."""
        m = Interaction()
        m.header.stamp = rospy.Time.from_sec(time.time())  # the soak runs on wall time
        m.header.frame_id = "map"
        m.device_id = self.name
        m.session = self.session if session is None else session
        with self.lock:
            m.request_id = self.next_request
            self.next_request += 1
        m.type, m.object_id, m.object, m.base_version = type_, object_id, obj, base_version
        return m

    def send(self, type_, obj, object_id=0, base_version=0, session=None):
        """Sends one change; its answer reaches on_result. Returns the request id."""
        m = self.interaction(type_, obj, object_id, base_version, session)
        with self.lock:
            self.pending[m.request_id] = (type_, object_id, m.session)
        self.pub.publish(m)
        return m.request_id

    def send_and_wait(self, m, timeout):
        """Sends the Interaction m (made by interaction()) and returns its InteractionResult,
        or None after timeout seconds."""
        with self.lock:
            self.pending[m.request_id] = (m.type, m.object_id, m.session)
            self.awaited[m.request_id] = None
        self.pub.publish(m)
        end = time.time() + timeout
        with self.answered:
            while self.awaited[m.request_id] is None and time.time() < end:
                self.answered.wait(0.1)
            return self.awaited.pop(m.request_id)

    def on_result(self, msg):
        with self.lock:
            if "session" not in msg.reason:
                self.answered_since_connect = True
            if msg.request_id in self.awaited:
                self.awaited[msg.request_id] = msg
                self.answered.notify_all()
            type_, object_id, sent_with = self.pending.pop(msg.request_id,
                                                           (None, msg.object_id, None))
            if msg.accepted:
                if type_ == Interaction.DELETE:
                    self.live.pop(msg.object_id, None)
                elif type_ is not None:
                    self.live[msg.object_id] = msg.version
            elif type_ in (Interaction.MANIPULATE, Interaction.DELETE) and \
                    object_id in self.live:  # (not another device's, tried on purpose)
                if msg.version:
                    self.live[object_id] = msg.version  # the server's: try again from there
                if "unknown" in msg.reason or "deleted" in msg.reason:
                    self.live.pop(object_id, None)
            if "session" in msg.reason and sent_with == self.session:
                self.session = 0  # a restarted server: connect again (not a wrong token on purpose)
        self.ledger.on_result(self.name, msg, deleted=type_ == Interaction.DELETE)
