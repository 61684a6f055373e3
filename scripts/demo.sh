#!/usr/bin/env bash
# The whole pipeline on the bundled datasets and the real logs in ../shared/data/real.
# Grows with the toolkit: import -> info (and, as they land, simulate, map, label, report).
set -euo pipefail
OUT=${OUT:-out}
REAL=${TOOLKIT_REAL_DATA:-../shared/data/real}
mkdir -p "$OUT/datasets"

imp() {  # imp NAME FORMAT SOURCE...
    local name=$1 fmt=$2; shift 2
    echo "== import $fmt $*"
    toolkit import "$fmt" "$@" --out "$OUT/datasets/$name" --force
    echo
}

if [[ -d $REAL ]]; then
    imp intel carmen "$REAL/carmen_radish_corrected/intel-corrected.log.gz"
    imp dpslam_loop5 auto "$REAL/dpslam_loop5/loop5.log"
    imp csm_laserazos carmen "$REAL/csm_laserazos/laserazosSM3.log"
else
    echo "no real logs at $REAL; skipping them"
fi
echo "datasets in $OUT/datasets/"
