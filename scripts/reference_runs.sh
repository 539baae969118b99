#!/bin/bash
# The reference scenes (A1-A6, desk, T-bar, T-bar gripper, D1-D8) with the Newton and PATH
# backends, for comparing two builds entry by entry (docs/latency.md):
#   scripts/reference_runs.sh ECP_BINARY OUT_DIR
#   python3 scripts/compare_trajectories.py OLD/newton/desk/trajectory.csv NEW/newton/desk/trajectory.csv
# Run from the repository root. A run that fails is named on stderr.
set -u
if [ $# -ne 2 ]; then echo "usage: $0 ECP_BINARY OUT_DIR" >&2; exit 2; fi
bin=$1; out=$2
for s in a1_sliding a2_push_slide a2_push_stick a3_spin a4_incline_10 a4_incline_25 a5_drop \
         a5_drop_tilted a6_tip_110 a6_tip_90 desk tbar tbar_gripper d1_stack d2_offset_stack \
         d3_block_on_block d4_conveyor d5_collision d6_incline_body d7_tower d8_edge_on_edge; do
  for solver in newton path; do
    "$bin" run "scenes/$s.toml" --solver "$solver" --no-plots --quiet --out "$out/$solver/$s" \
      > /dev/null 2>&1 || echo "FAIL $s $solver" >&2
  done
done
