"""Every VO change the server acknowledged (an accepted ecar_msgs/InteractionResult on some
/<device>/interaction_result), and the check that the VO database still holds it.

The server commits a change to SQLite before it answers, so an acknowledged change must survive
anything: a kill -9, a restart from an older autosave, a full disk. A change is lost when the
database has no row for the object, or an older version than the one acknowledged, or (for an
acknowledged delete) a live object at that version.

    ledger = VoLedger()
    ledger.on_result("device_0", result_msg)            # from the result topics
    ledger.on_result("soak_editor", msg, deleted=True)  # the editor knows its deletes
    lost = ledger.check(read_database("out/soak/db/vo.sqlite"))
"""

import collections
import os
import shutil
import sqlite3
import threading

Acked = collections.namedtuple("Acked", "version device deleted")
Loss = collections.namedtuple("Loss", "object_id acked_version device found")


def read_database(path, copy_to=None):
    """{object id: (version, deleted)} of the VO database at path (ecar's schema: table objects).
    copy_to: a folder to copy the database and its write-ahead log into first and read there,
    so that the server's files are never touched (and can be read on a full disk). Raises
    RuntimeError naming the file when it cannot be read."""
    if not os.path.isfile(path):
        raise RuntimeError("reading the VO database %s: no such file" % path)
    if copy_to:
        os.makedirs(copy_to, exist_ok=True)
        for suffix in ("", "-wal"):
            target = os.path.join(copy_to, os.path.basename(path) + suffix)
            for stale in (target, target.replace("-wal", "") + "-shm"):
                if os.path.exists(stale):
                    os.remove(stale)
            if os.path.exists(path + suffix):
                shutil.copyfile(path + suffix, target)
        path = os.path.join(copy_to, os.path.basename(path))
    try:
        # The first reader after a kill -9 recovers the write-ahead log's index.
        db = sqlite3.connect(path, timeout=10.0)
        try:
            rows = db.execute("SELECT id, version, deleted FROM objects").fetchall()
        finally:
            db.close()
    except sqlite3.Error as e:
        raise RuntimeError("reading the VO database %s: %s" % (path, e))
    return {int(i): (int(v), bool(d)) for i, v, d in rows}


class VoLedger:
    """The newest acknowledged version of every object (thread-safe: results arrive on rospy's
    threads)."""

    def __init__(self):
        self._lock = threading.Lock()
        self._acked = {}  # object id -> Acked
        self.accepted = 0  # accepted results seen
        self.rejected = collections.Counter()  # reason (first words) -> count

    def on_result(self, device, msg, deleted=False):
        """Records one InteractionResult of `device`; deleted: the request was a DELETE."""
        with self._lock:
            if not msg.accepted:
                self.rejected[reason_kind(msg.reason)] += 1
                return
            self.accepted += 1
            known = self._acked.get(msg.object_id)
            if known is None or msg.version >= known.version:
                self._acked[msg.object_id] = Acked(msg.version, device, deleted)

    def acked(self):
        """{object id: Acked}, a copy."""
        with self._lock:
            return dict(self._acked)

    def check(self, rows):
        """The acknowledged changes that `rows` (read_database) lacks, by object id."""
        lost = []
        for object_id, a in sorted(self.acked().items()):
            found = rows.get(object_id)
            if found is None:
                lost.append(Loss(object_id, a.version, a.device, "no row"))
            elif found[0] < a.version:
                lost.append(Loss(object_id, a.version, a.device, "version %d" % found[0]))
            elif a.deleted and found[0] == a.version and not found[1]:
                lost.append(Loss(object_id, a.version, a.device, "live, deleted at that version"))
        return lost


def reason_kind(reason):
    """A rejection's reason shortened to its kind for counting: up to the first ':' or 6 words
    ("stale version", "session", ...)."""
    head = reason.split(":")[0].strip() if ":" in reason[:40] else reason
    return " ".join(head.split()[:6]) or "(no reason)"
