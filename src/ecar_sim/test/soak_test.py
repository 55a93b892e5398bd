#!/usr/bin/python3
"""Tests of the soak's parts that need no ROS master (python/ecar_sim/soak): the ledger of
acknowledged VO changes against a real SQLite database of ecar's schema, the memory growth per
server life, the local graph status read from raw bytes, the JPEG header patch of the bomb
input, the command line, and the report of a summary."""

import io
import os
import sqlite3
import sys
import tempfile
import unittest

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))
from ecar_msgs.msg import InteractionResult, LocalGraph  # noqa: E402
from ecar_msgs.msg import Interaction  # noqa: E402
from ecar_sim.soak import editor, hostile, ledger, memory, monitor, options, report  # noqa: E402
from sensor_msgs.msg import CameraInfo  # noqa: E402


def result(object_id, version, accepted=True, reason=""):
    return InteractionResult(object_id=object_id, version=version, accepted=accepted,
                             reason=reason)


def database(folder, rows):
    """A VO database file with ecar's objects table holding rows (id, version, deleted)."""
    path = os.path.join(folder, "vo.sqlite")
    with sqlite3.connect(path) as db:
        db.execute("PRAGMA journal_mode=WAL")
        db.execute("CREATE TABLE objects (id INTEGER PRIMARY KEY, version INTEGER NOT NULL, "
                   "deleted INTEGER NOT NULL)")
        db.executemany("INSERT INTO objects VALUES (?, ?, ?)", rows)
    return path


class LedgerTest(unittest.TestCase):
    def test_kept_changes_pass_and_each_kind_of_loss_is_named(self):
        led = ledger.VoLedger()
        led.on_result("device_0", result(1, 1))
        led.on_result("device_0", result(1, 3))
        led.on_result("device_0", result(1, 2))  # an older answer arriving late
        led.on_result("device_1", result(2, 1))
        led.on_result("soak_editor", result(3, 2), deleted=True)
        led.on_result("soak_editor", result(4, 5))
        led.on_result("device_0", result(9, 0, accepted=False, reason="stale base_version 1: x"))
        self.assertEqual(led.acked()[1].version, 3)
        self.assertEqual(led.accepted, 6)
        with tempfile.TemporaryDirectory() as tmp:
            # 1 newer than acknowledged (fine), 2 missing, 3 live at its delete's version,
            # 4 reverted to an older version.
            path = database(tmp, [(1, 4, 0), (3, 2, 0), (4, 4, 0), (7, 1, 0)])
            lost = led.check(ledger.read_database(path, copy_to=os.path.join(tmp, "copy")))
        self.assertEqual([(l.object_id, l.found) for l in lost],
                         [(2, "no row"), (3, "live, deleted at that version"),
                          (4, "version 4")])
        self.assertEqual(led.rejected, {"stale base_version 1": 1})

    def test_a_deleted_tombstone_at_the_version_is_kept(self):
        led = ledger.VoLedger()
        led.on_result("soak_editor", result(3, 2), deleted=True)
        self.assertEqual(led.check({3: (2, True)}), [])

    def test_reading_a_copy_leaves_the_database_alone_and_sees_the_log(self):
        with tempfile.TemporaryDirectory() as tmp:
            path = database(tmp, [(1, 1, 0)])
            writer = sqlite3.connect(path)
            writer.execute("PRAGMA wal_autocheckpoint=0")
            writer.execute("INSERT INTO objects VALUES (2, 1, 0)")
            writer.commit()  # in the write-ahead log only
            self.assertGreater(os.path.getsize(path + "-wal"), 0)
            before = os.stat(path).st_mtime_ns
            rows = ledger.read_database(path, copy_to=os.path.join(tmp, "copy"))
            writer.close()
            self.assertEqual(rows, {1: (1, False), 2: (1, False)})
            self.assertEqual(os.stat(path).st_mtime_ns, before)

    def test_a_missing_or_foreign_file_is_an_error_naming_it(self):
        with tempfile.TemporaryDirectory() as tmp:
            with self.assertRaisesRegex(RuntimeError, "nothing.sqlite: no such file"):
                ledger.read_database(os.path.join(tmp, "nothing.sqlite"))
            other = os.path.join(tmp, "other.sqlite")
            sqlite3.connect(other).execute("CREATE TABLE t (x)").connection.close()
            with self.assertRaisesRegex(RuntimeError, "other.sqlite: no such table: objects"):
                ledger.read_database(other)

    def test_reason_kinds(self):
        self.assertEqual(ledger.reason_kind("session: wrong session token (field session)"),
                         "session")
        self.assertEqual(ledger.reason_kind(
            "soak_editor sent more than 50 interactions a second (vo.max_interaction_rate)"),
            "soak_editor sent more than 50 interactions")
        self.assertEqual(ledger.reason_kind(""), "(no reason)")


def samples(life, start, seconds, kib, slope=0.0, every=2.0):
    return [memory.Sample(start + i * every, life, kib + slope * i * every, 1000, None, None)
            for i in range(int(seconds / every))]


class MemoryTest(unittest.TestCase):
    def test_growth_per_life_after_warm_up(self):
        s = samples(1, 0.0, 400.0, 100000.0, slope=25.0)  # 25 KiB/s
        s += samples(2, 400.0, 100.0, 90000.0)  # too short to judge
        lives = memory.growth(s, warmup=120.0)
        self.assertEqual([l.index for l in lives], [1, 2])
        first, second = lives
        self.assertTrue(first.judged)
        # base: median over 120..150 s (~103375 KiB), end: over the last 30 s (~109625).
        self.assertAlmostEqual(first.base_kib, 100000 + 25 * 134, delta=100)
        self.assertAlmostEqual(first.percent, 100.0 * 25 * 250 / first.base_kib, delta=0.5)
        self.assertFalse(second.judged)
        self.assertIsNone(second.percent)

    def test_a_spike_does_not_make_a_trend(self):
        s = samples(1, 0.0, 300.0, 100000.0)
        s[-3] = s[-3]._replace(server_kib=180000)
        self.assertAlmostEqual(memory.growth(s, warmup=60.0)[0].percent, 0.0)

    def test_growth_of_one_part(self):
        # Anonymous memory growing 20 KiB/s, the total flat: each field judged on its own.
        s = [x._replace(server_anon_kib=50000 + 20 * x.t, server_file_kib=40000)
             for x in samples(1, 0.0, 300.0, 100000.0)]
        anon = memory.growth(s, 60.0, "server_anon_kib")[0]
        self.assertAlmostEqual(anon.percent, 100.0 * 20 * 195 / anon.base_kib, delta=1.0)
        self.assertAlmostEqual(memory.growth(s, 60.0, "server_file_kib")[0].percent, 0.0)
        self.assertAlmostEqual(memory.growth(s, 60.0)[0].percent, 0.0)
        self.assertEqual(memory.growth(samples(1, 0.0, 300.0, 1.0), 60.0, "server_anon_kib"), [])

    def test_rss_of_this_process_and_of_none(self):
        self.assertGreater(memory.rss_kib(os.getpid()), 1000)
        self.assertIsNone(memory.rss_kib(None))
        self.assertIsNone(memory.rss_kib(2 ** 22 + 12345))
        anon, mapped = memory.rss_parts_kib(os.getpid())
        self.assertGreater(anon, 100)
        self.assertGreater(mapped, 100)
        self.assertLessEqual(anon + mapped, memory.rss_kib(os.getpid()) + 1024)
        self.assertEqual(memory.rss_parts_kib(None), (None, None))


class GraphStatusTest(unittest.TestCase):
    def test_fields_read_from_the_serialised_graph(self):
        g = LocalGraph(device_id="device_7", frame_index=1234, status=LocalGraph.RELOCALISED,
                       map_epoch=3)
        g.header.frame_id = "map"
        g.pose.orientation.w = 1.0
        buff = io.BytesIO()
        g.serialize(buff)
        self.assertEqual(monitor.graph_status(buff.getvalue()),
                         ("device_7", 1234, LocalGraph.RELOCALISED, 3))


class RecoveryTest(unittest.TestCase):
    def test_a_restarted_device_counts_only_its_new_frames(self):
        mon = monitor.Monitor(["device_0"], ledger.VoLedger())
        cb = mon._graph_cb("device_0")

        class Raw:
            def __init__(self, frame, status):
                g = LocalGraph(device_id="device_0", frame_index=frame, status=status)
                g.pose.orientation.w = 1.0
                buff = io.BytesIO()
                g.serialize(buff)
                self._buff = buff.getvalue()
        cb(Raw(2400, LocalGraph.OK))
        t = mon.aligned["device_0"][-1][0]
        self.assertEqual(mon.last_frame("device_0"), 2400)
        cb(Raw(2404, LocalGraph.OK))  # the killed process's last upload, answered late
        cb(Raw(8, LocalGraph.LOST))  # the new process, not aligned yet
        cb(Raw(12, LocalGraph.RELOCALISED))
        self.assertEqual(mon.graphs["device_0"], 4)
        got = mon.first_aligned_after("device_0", t - 1e-6, below=2400)
        self.assertEqual(got, mon.aligned["device_0"][-1][0])
        self.assertEqual(mon.first_aligned_after("device_0", t - 1e-6),
                         mon.aligned["device_0"][0][0])
        self.assertIsNone(mon.first_aligned_after("device_0", t + 60.0))


class HostileTest(unittest.TestCase):
    def test_the_bomb_patch_changes_only_the_size(self):
        # SOI, an APP0 segment, SOF0 (precision 8, 480 x 640, 1 component), EOI.
        jpeg = (b"\xff\xd8" + b"\xff\xe0\x00\x04ab" +
                b"\xff\xc0\x00\x0b\x08\x01\xe0\x02\x80\x01\x01\x11\x00" + b"\xff\xd9")
        bomb = hostile._patched_size(jpeg, 65000, 60000)
        self.assertEqual(len(bomb), len(jpeg))
        self.assertEqual(bomb[13:17], (60000).to_bytes(2, "big") + (65000).to_bytes(2, "big"))
        self.assertEqual(bomb[:13] + bomb[17:], jpeg[:13] + jpeg[17:])
        with self.assertRaisesRegex(ValueError, "no SOF marker"):
            hostile._patched_size(b"\xff\xd8\xff\xd9" + b"\x00" * 12, 1, 1)

    def test_every_kind_has_a_description(self):
        kinds = [n for n in dir(hostile.Hostile) if n.startswith("kind_")]
        self.assertGreaterEqual(len(kinds), 20)
        for n in kinds:
            self.assertTrue((getattr(hostile.Hostile, n).__doc__ or "").strip(), n)


class EditorTest(unittest.TestCase):
    """The editor's own bookkeeping from the answers (no master: nothing is sent)."""

    def answer(self, ed, type_, object_id, accepted, version, reason="", session=None):
        m = ed.interaction(type_, editor.line(0.0, 0.0), object_id, 1, session)
        with ed.lock:
            ed.pending[m.request_id] = (type_, object_id, m.session)
        ed.on_result(InteractionResult(request_id=m.request_id, object_id=object_id,
                                       accepted=accepted, version=version, reason=reason))

    def test_answers_keep_its_objects_and_its_token(self):
        import random
        led = ledger.VoLedger()
        ed = editor.VoEditor(CameraInfo(), led, random.Random(1))
        ed.session = 77
        self.answer(ed, Interaction.REGISTER, 5, True, 1)
        self.answer(ed, Interaction.MANIPULATE, 5, True, 2)
        self.assertEqual(ed.live, {5: 2})
        # A delete of another device's object, refused: not one of its own.
        self.answer(ed, Interaction.DELETE, 9, False, 4, "deleting object 9 is for its owner")
        self.assertEqual(ed.live, {5: 2})
        # A conflict on its own: the server's version, to try again from.
        self.answer(ed, Interaction.MANIPULATE, 5, False, 3, "stale base_version 2: ...")
        self.assertEqual(ed.live, {5: 3})
        # A wrong token on purpose keeps the real one; a rejection of the real one drops it.
        self.answer(ed, Interaction.REGISTER, 0, False, 0, "session: wrong session token",
                    session=1234)
        self.assertEqual(ed.session, 77)
        self.answer(ed, Interaction.REGISTER, 0, False, 0, "session: wrong session token")
        self.assertEqual(ed.session, 0)
        self.answer(ed, Interaction.DELETE, 5, True, 4)
        self.assertEqual(ed.live, {})
        self.assertTrue(led.acked()[5].deleted)


class OptionsTest(unittest.TestCase):
    def test_defaults_pick_the_corridor_devices_that_start_at_one_end(self):
        a = options.parse_args(["--devices", "3"], cwd="/tmp")
        self.assertEqual(a.device_names, "device_0,device_3,device_4")
        self.assertEqual(a.out, os.path.join(options.REPO_ROOT, "out", "soak"))

    def test_bad_values_are_usage_errors(self):
        for argv in (["--minutes", "0"], ["--disk-full-at", "1.5"], ["--kill-every", "-1"],
                     ["--frames", "3"], ["--devices", "99"]):
            with self.assertRaises(SystemExit, msg=argv), \
                    open(os.devnull, "w") as null:
                stderr, sys.stderr = sys.stderr, null
                try:
                    options.parse_args(argv, cwd="/tmp")
                finally:
                    sys.stderr = stderr


class ReportTest(unittest.TestCase):
    def test_markdown_names_every_failure_and_every_hostile_row(self):
        s = {"passed": False, "failures": ["1 acknowledged VO change(s) lost"],
             "devices": ["device_0"], "scene": "/x/corridor.yaml", "frames": 160,
             "minutes": 2.5, "kill_every_s": 50, "restart_devices_every_s": 0,
             "disk_full": None,
             "memory": {"lives": [{"index": 1, "start": 0, "end": 50, "base_kib": None,
                                   "end_kib": 150000, "percent": None}],
                        "window_s": 30.0, "server_peak_mb": 150.0, "devices_peak_mb": 90.0,
                        "max_growth_percent": None},
             "faults": {"server_kills": 1, "device_restarts": 0, "events": []},
             "recovery": {"recoveries": 2, "unrecovered": [], "median_s": 2.0, "max_s": 3.0},
             "vo": {"acknowledged_objects": 10, "accepted_results": 12, "lost": [{}],
                    "checks": [{"when": "after kill 1", "t": 51.0, "acked": 10, "rows": 9,
                                "lost": [{}]}],
                    "rejected_by_reason": {"session": 2}},
             "hostile": [{"kind": "upload_png", "what": "png", "sent": 2, "refused": 2,
                          "outcome": "dropped | x"}],
             "crashes": []}
        text = report.markdown(s)
        self.assertIn("FAILED: 1 acknowledged VO change(s) lost", text)
        self.assertIn("| upload_png | png | 2 | 2 | dropped / x |", text)
        self.assertIn("after kill 1 (51 s): 10 acknowledged, 9 rows, 1 lost", text)
        self.assertIn("not judged", text)


if __name__ == "__main__":
    import rosunit
    rosunit.unitrun("ecar_sim", "soak", "__main__")
