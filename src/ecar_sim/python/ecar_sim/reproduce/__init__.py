"""The paper's experiments, one command each (scripts/reproduce.sh): runs, CSV, plots and
REPORT.md under out/reproduce/."""
