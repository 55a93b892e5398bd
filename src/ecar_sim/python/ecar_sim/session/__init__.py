"""run_session as a package: one measured eCAR session (see scripts/run_session).

  options      the command line; every path made absolute where the user stands
  datasets     the scene's devices and their rendered datasets (make_dataset, reused)
  launching    the ROS master, server, devices and players as child processes; liveness
  collecting   the subscribers that record metrics, device frames, local graphs, VOs
  evaluating   per-device and overall metrics, pacing, summary.json, metrics.csv, traj/
  structure    the VO and plane metrics (map -> world fit) and vo_raw.json.gz
  report       the printed lines: progress during playback, the summary
  runner       the session from start to summary, and --reevaluate
"""
