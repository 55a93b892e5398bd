"""eCAR's Python tools: run_session (ecar_sim.session), the session metrics (vo_metrics,
plane_metrics, ground_truth) and the alignment they share with ground_truth_aligner."""
