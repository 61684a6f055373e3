#!/usr/bin/env bash
# The whole pipeline on the bundled datasets (datasets/catalog.json) and, when they are
# there, the real logs in ../shared/data/real: import -> map -> label -> report.
set -euo pipefail
OUT=${OUT:-out}
REAL=${TOOLKIT_REAL_DATA:-../shared/data/real}
DATA=$OUT/datasets
RUNS=$OUT/runs

step() { echo; echo "== $*"; }
imp() {  # imp NAME FORMAT SOURCE... [options]
    local name=$1 fmt=$2; shift 2
    step "import $fmt $*"
    toolkit import "$fmt" "$@" --out "$DATA/$name" --force
}

# 1. Import: the bundled simulated logs, each in a native format, and the real logs.
imp corridor auto datasets/corridor-carmen/sim.log.gz
imp corridor_aria aria datasets/corridor-aria/log.2d.gz
imp corridor_lms200 lms200 datasets/corridor-lms200/capture.lms
imp building rawseeds datasets/building-rawseeds
if [[ -d $REAL ]]; then
    imp intel carmen "$REAL/carmen_radish_corrected/intel-corrected.log.gz" -O poses=groundtruth
    imp dpslam_loop5 auto "$REAL/dpslam_loop5/loop5.log"
    imp csm_laserazos carmen "$REAL/csm_laserazos/laserazosSM3.log"
    imp ccny_bag auto "$REAL/ccny_scan_tools_bags/laser_scan_matcher/demo.bag"
else
    echo "no real logs at $REAL; skipping them"
fi

# 2. Map: odometry alone, the Gaussian matcher and ICP on the corridor; Gaussian elsewhere.
for method in odometry gaussian icp; do
    step "map corridor --method $method"
    toolkit map "$DATA/corridor" --out "$RUNS/corridor-$method" --method "$method" --force
done
step "map building"
toolkit map "$DATA/building" --out "$RUNS/building-gaussian" --force
if [[ -d $REAL ]]; then
    step "map dpslam_loop5 (raw odometry, no ground truth)"
    toolkit map "$DATA/dpslam_loop5" --out "$RUNS/dpslam_loop5-gaussian" --force
fi

# 3. Label: places taught from 10 scans each, along the corrected trajectory, with the default
# model (scan descriptors, docs/places.md) on every log.
step "label corridor"
toolkit label "$DATA/corridor" --regions datasets/corridor-carmen/regions.csv \
    --truth datasets/corridor-carmen/truth.parquet \
    --trajectory "$RUNS/corridor-gaussian/trajectory.parquet" --out "$RUNS/corridor-labels" --force
step "label building"
toolkit label "$DATA/building" --regions datasets/building-rawseeds/regions.csv \
    --truth datasets/building-rawseeds/truth.parquet \
    --trajectory "$RUNS/building-gaussian/trajectory.parquet" --out "$RUNS/building-labels" --force
if [[ -d $REAL ]]; then
    step "label intel (corridor vs room, regions chosen on its map)"
    toolkit label "$DATA/intel" --regions datasets/real-regions/intel-regions.csv \
        --out "$RUNS/intel-labels" --force
fi

# 4. Report: the paper's tables and figures, measured in this run.
step "report"
real_opt=(--no-real)
[[ -d $REAL ]] && real_opt=(--real "$REAL")
toolkit report --out "$OUT/report" "${real_opt[@]}" --force
echo
echo "datasets in $DATA/, runs in $RUNS/, report: $OUT/report/index.html"
