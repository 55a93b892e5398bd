"""One measured session from start to summary (run), and --reevaluate (reevaluate).

run: the datasets (datasets.py), the ROS master, server, devices and players (launching.py),
the records while the datasets play (collecting.py), with a progress line every
PROGRESS_PERIOD_S and an end at once when a child dies, then the summary (evaluating.py,
structure.py, report.py). Exit status: 0, 1 when the sequences did not finish within the
timeout, 2 on an error (a child died, the server did not come up).
"""

import os
import shutil
import time

import rospy
from std_msgs.msg import Time

from ecar_sim import links
from ecar_sim.session import evaluating, launching, maps, options, structure
from ecar_sim.session.collecting import Collector
from ecar_sim.session.datasets import dataset_frames, ensure_datasets, read_fps, scene_devices
from ecar_sim.session.report import log, print_summary, progress_line

PROGRESS_PERIOD_S = 5.0  # between progress lines during playback
SETTLE_S = 3.0  # quiet time after every player finished before the session ends
MASTER_TIMEOUT_S = 30.0
CONNECT_TIMEOUT_S = 60.0  # for the server's /ecar/connect, and for the devices' topics
POLL_S = 0.5
LIGHT_START_DELAY_S = 0.5  # from publishing the start time to the light devices' first frame


def main(argv, description=None):
    """run_session's entry point: the exit status."""
    args = options.parse_args(argv, description)
    if args.reevaluate:
        return reevaluate(args)
    return run(args)


def prepare_out(out):
    """Creates out, removes a previous session's VO database and logs; returns out/logs."""
    os.makedirs(out, exist_ok=True)
    for stale in ("vo.sqlite", "vo.sqlite-wal", "vo.sqlite-shm"):
        if os.path.exists(os.path.join(out, stale)):
            os.remove(os.path.join(out, stale))
    log_dir = os.path.join(out, "logs")
    if os.path.isdir(log_dir):
        shutil.rmtree(log_dir)
    os.makedirs(log_dir)
    return log_dir


def session_env(port, log_dir, hosts=None):
    """The environments of the session's children on each host, {"server": env, "devices":
    env}: its own master, logs in log_dir, output flushed line by line so that a log is
    complete up to a crash. On loopback (hosts None or not shaped) both are one, on
    127.0.0.1; on a shaped link each host's nodes announce its address (ROS_IP) and find the
    master on the server host, as on two machines. This process's rospy gets the same master
    (on a shaped link from the observer host, links.Hosts)."""
    env = dict(os.environ)
    env.update({"ROS_LOG_DIR": log_dir, "PYTHONUNBUFFERED": "1",
                "ROSCONSOLE_STDOUT_LINE_BUFFERED": "1"})
    if hosts is None or not hosts.profile.shaped:
        env.update({"ROS_MASTER_URI": "http://127.0.0.1:%d" % port, "ROS_HOSTNAME": "127.0.0.1"})
        env.pop("ROS_IP", None)
        os.environ.update({k: env[k] for k in ("ROS_MASTER_URI", "ROS_HOSTNAME", "ROS_LOG_DIR")})
        os.environ.pop("ROS_IP", None)
        return {"server": env, "devices": env}
    uri = hosts.master_uri(port)
    os.environ.update(hosts.observer.env(uri, {}))
    os.environ["ROS_LOG_DIR"] = log_dir
    os.environ.pop("ROS_HOSTNAME", None)
    return {"server": hosts.server.env(uri, env), "devices": hosts.devices.env(uri, env)}


def report_deaths(error):
    """The error lines of a ChildDied: each dead child, why, and the end of its log."""
    for child, why in error.deaths:
        log("error: %s died (%s); last lines of %s:" % (child.what, why, child.log_path))
        for line in child.tail():
            log("    " + line)


def progress_text(collector, frames, fps, elapsed, every=1):
    """The progress line of the session so far (see report.progress_line). every: dataset
    frames per recorded frame (light devices record only their uploads, every `every`th)."""
    prog = collector.progress()
    played = {d: (p.frames - 1) * every + 1 if p.frames else 0 for d, p in prog.items()}
    rate = evaluating.playback_rate(
        {d: (played[d], p.first_wall, p.last_wall) for d, p in prog.items()}, fps)
    return progress_line(elapsed, played, frames,
                         {d: p.uploads for d, p in prog.items()},
                         {d: p.graphs for d, p in prog.items()}, rate)


def uplink_capacity(args, profile):
    """The uplink capacity the server is told (bytes/s, in the session's scaled time): the
    shaped link's up rate with --upload-budget link, else None (the server's config file)."""
    if getattr(args, "upload_budget", "link") != "link" or not profile.shaped:
        return None
    return profile.up_bytes_per_s


def start_nodes(args, hosts, envs, port, devices, datasets, procs):
    """The ROS master (on port) and the server on the server host, the devices on the devices
    host; returns once the server's /ecar/connect is up. Also writes the session's launch
    files into args.out."""
    procs.start("roscore", "the ROS master", hosts.server.wrap(["roscore", "-p", str(port)]),
                envs["server"])
    master = launching.wait_for_master(envs["server"]["ROS_MASTER_URI"], MASTER_TIMEOUT_S,
                                       procs)
    server = launching.server_include(args, uplink_capacity(args, hosts.profile))
    if args.light:
        device_includes = {"light_devices": launching.light_devices_include(args, devices,
                                                                           datasets)}
    else:
        device_includes = {d: launching.device_include(args, d) for d in devices}
        launching.write_launch(os.path.join(args.out, "session_players.launch"),
                               [launching.player_include(args, d, datasets[d]) for d in devices])
    launching.write_launch(os.path.join(args.out, "session_nodes.launch"),
                           [server] + list(device_includes.values()))
    procs.start("server", "the server", hosts.server.wrap(server.command()), envs["server"])
    for d, inc in device_includes.items():
        what = "the light devices" if args.light else "device %s" % d
        procs.start(d, what, hosts.devices.wrap(inc.command()), envs["devices"])
    # Devices connect once their camera_info arrives (it carries the intrinsics), so the
    # players start as soon as the server's connect service is up.
    deadline = time.time() + CONNECT_TIMEOUT_S
    while not launching.service_exists(master, "/ecar/connect"):
        procs.check()
        if time.time() > deadline:
            raise RuntimeError("the server's /ecar/connect did not appear within %.0f s (see %s)"
                               % (CONNECT_TIMEOUT_S, procs.log_dir))
        time.sleep(0.2)


def play(args, hosts, envs, devices, datasets, procs, collector, frames, fps, timeout):
    """Starts the players (on the devices host) and waits until every dataset has played and
    the last messages are in; returns (wall seconds, finished in time). Raises ChildDied when
    a child dies."""
    deadline = time.time() + CONNECT_TIMEOUT_S
    while collector.unconnected():
        procs.check()
        if time.time() > deadline:
            raise RuntimeError("not connected to the devices' %s within %.0f s (see %s)" %
                               (", ".join(collector.unconnected()), CONNECT_TIMEOUT_S,
                                procs.log_dir))
        time.sleep(0.05)
    log("server up; playing %d %sdevice(s)" % (len(devices), "light " if args.light else ""))
    start = time.time()
    if args.light:
        # All together, once every device is listened to (they wait for this time).
        starter = rospy.Publisher(launching.START_TOPIC, Time, queue_size=1, latch=True)
        starter.publish(rospy.Time.from_sec(start + LIGHT_START_DELAY_S))
    for d in ([] if args.light else devices):
        procs.start("%s_player" % d, "the player of %s" % d,
                    hosts.devices.wrap(launching.player_include(args, d, datasets[d]).command()),
                    envs["devices"])
    next_progress = start + PROGRESS_PERIOD_S
    while time.time() < start + timeout:
        done, idle = collector.all_finished()
        if done and idle > SETTLE_S:
            return time.time() - start, True
        procs.check()
        if time.time() >= next_progress:
            log(progress_text(collector, frames, fps, time.time() - start,
                              every=args.every if args.light else 1))
            next_progress += PROGRESS_PERIOD_S
        time.sleep(POLL_S)
    log("timeout after %.0f s: sequences not finished" % timeout)
    return time.time() - start, False


def run(args):
    """A whole session (args from options.parse_args); the exit status."""
    out = args.out
    log_dir = prepare_out(out)
    scene_name, devices = scene_devices(args.scene, args.devices, args.device_names)
    try:
        profile = links.LinkProfile.find(args.link, os.path.join(options.REPO_ROOT, "config",
                                                                 "links"))
        if profile.shaped and args.rate != 1.0:
            log("scaled time: playback at rate %g, so the link's rates too: up %.3f MB/s, down "
                "%.3f MB/s (%s's %.3f and %.3f)" % (
                    args.rate, profile.up_bytes_per_s * args.rate / 1e6,
                    profile.down_bytes_per_s * args.rate / 1e6, profile.name,
                    profile.up_bytes_per_s / 1e6, profile.down_bytes_per_s / 1e6))
            profile = profile.scaled(args.rate)
        with links.Hosts(profile, observer=True) as hosts:
            for name in hosts.removed_leftovers:
                log("removed network namespace %s of a run that ended without cleaning up" %
                    name)
            return _run_on(args, out, log_dir, scene_name, devices, hosts)
    except links.LinkError as e:
        log("error: " + str(e))
        return 2


def _run_on(args, out, log_dir, scene_name, devices, hosts):
    """run() on the hosts of the session's link."""
    port = launching.free_port()
    envs = session_env(port, log_dir, hosts)
    env = envs["server"]

    try:
        datasets = ensure_datasets(args, env, scene_name, devices)
    except RuntimeError as e:
        log("error: " + str(e))
        return 2
    frames = {d: dataset_frames(datasets[d]) for d in devices}
    fps = read_fps(datasets[devices[0]])
    timeout = args.timeout or 4.0 * max(frames.values()) / fps / args.rate + 120.0
    log("%d device(s) %s, %s mode, every %d, JPEG %d, rate %g, link %s, master on %s" %
        (len(devices), ",".join(devices), args.sync_mode, args.every, args.jpeg_quality,
         args.rate, hosts.profile.name, envs["server"]["ROS_MASTER_URI"]))

    procs = launching.Processes(log_dir)
    try:
        start_nodes(args, hosts, envs, port, devices, datasets, procs)
        rospy.init_node("run_session", anonymous=True, disable_signals=True)
        collector = Collector(devices, metrics_publishers=1 if args.light else None,
                              ar_views=getattr(args, "ar_views", False))
        sent_before = hosts.counters()
        wall, in_time = play(args, hosts, envs, devices, datasets, procs, collector, frames,
                             fps, timeout)
        sent_after = hosts.counters()
    except launching.ChildDied as e:
        report_deaths(e)
        return 2
    except RuntimeError as e:
        log("error: " + str(e))
        return 2
    finally:
        if rospy.core.is_initialized():
            rospy.signal_shutdown("session over")
        procs.stop_all()

    traj_dir = os.path.join(out, "traj")
    os.makedirs(traj_dir, exist_ok=True)
    final = maps.final_map(collector, devices)
    per_device = {d: evaluating.device_summary(d, datasets[d], collector, traj_dir, env,
                                               final=final, uploads_only=args.light)
                  for d in devices}
    overall = evaluating.overall_summary(
        devices, collector, time_scale=args.rate if hosts.profile.shaped else 1.0)
    structure.save_raw(os.path.join(out, "vo_raw.json.gz"), collector)
    vo, planes = structure.evaluate_structure(args, devices, datasets, collector)
    spans = {d: (frames[d], collector.first_frame_wall.get(d), collector.last_frame_wall.get(d))
             for d in devices}
    pacing = evaluating.pacing_summary(
        args.rate, evaluating.playback_rate(spans, fps), wall, args.pacing,
        sum(r["frames_skipped"] or 0 for r in per_device.values()))
    sent = None if sent_before is None else {k: sent_after[k] - sent_before[k]
                                             for k in sent_before}
    link = evaluating.link_summary(hosts.profile, sent, wall, time_scale=args.rate)
    summary = evaluating.build_summary(args, devices, pacing, per_device, overall, vo, planes,
                                       link)
    evaluating.write_summary(out, summary)
    evaluating.write_metrics_csv(out, collector.metrics)
    for d, image in sorted(collector.ar_views.items()):
        path = os.path.join(out, "ar_view_%s.png" % d)
        write_image(image, path)
        log("wrote %s (frame %d)" % (path, image.header.seq))
    print_summary(summary, out)
    return 0 if in_time else 1


def write_image(msg, path):
    """A bgr8 or mono8 sensor_msgs/Image as a PNG file."""
    import numpy as np
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    channels = 3 if msg.encoding in ("bgr8", "rgb8") else 1
    img = np.frombuffer(msg.data, np.uint8).reshape(msg.height, msg.step)[:, :msg.width * channels]
    if channels == 3:
        img = img.reshape(msg.height, msg.width, 3)
        if msg.encoding == "bgr8":
            img = img[:, :, ::-1]
        plt.imsave(path, img)
    else:
        plt.imsave(path, img, cmap="gray", vmin=0, vmax=255)


def reevaluate(args):
    """Recomputes the VO and plane metrics of the session in args.out from its
    vo_raw.json.gz, rewrites summary.json and prints the summary."""
    out = args.out
    summary = evaluating.read_summary(out)
    records = structure.RawCollector(os.path.join(out, "vo_raw.json.gz"))
    args.scene = summary["scene"]
    args.vo_range = summary.get("vo_range", args.vo_range)
    devices = summary["devices"]
    datasets = {d: summary["per_device"][d]["dataset"] for d in devices}
    summary["vo"], summary["planes"] = structure.evaluate_structure(args, devices, datasets,
                                                                    records)
    evaluating.write_summary(out, summary)
    print_summary(summary, out)
    return 0
