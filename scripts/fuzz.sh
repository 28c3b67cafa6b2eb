#!/usr/bin/env bash
# Runs every libFuzzer target (fuzz/, issues 18 and 43) for SECONDS each (default 60), one after
# the other, and prints executions, corpus and crashes per target.
#
#   scripts/fuzz.sh [SECONDS]                      all targets
#   FUZZ_TARGETS="fits_lut camera_toml" scripts/fuzz.sh 600   some of them
#
# Needs nightly (preinstalled here) and cargo-fuzz (installed when missing). Each target
# reads the committed seeds (fuzz/corpus/<target>/) and the regressions
# (fuzz/regressions/<target>/) and writes what it finds to fuzz/target/corpus/<target>/,
# so the committed corpus stays small; merge by hand (`-merge=1`) what is worth keeping.
# Crashes land in fuzz/artifacts/<target>/; each fixed one becomes a file of
# fuzz/regressions/<target>/, which `cargo test` replays (core/tests/fuzz_corpus.rs,
# host-sim/tests/fuzz_corpus.rs).
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-60}
targets=(${FUZZ_TARGETS:-lut_image_chunks fits_histograms fits_linearity fits_lut emva_descriptor camera_toml analysis_linearity analysis_histograms analysis_lut})

cargo fuzz --version >/dev/null 2>&1 || cargo install cargo-fuzz --locked
cargo +nightly fuzz build
# The FITS, EMVA and TOML targets write every input to a temporary file: memory is faster.
if [[ -z "${TMPDIR:-}" && -d /dev/shm && -w /dev/shm ]]; then
    export TMPDIR=/dev/shm
fi

mkdir -p fuzz/target/logs
failed=()
printf '%-18s %8s %12s %10s %8s\n' target seconds executions corpus crashes
for t in "${targets[@]}"; do
    work=fuzz/target/corpus/$t
    mkdir -p "$work" "fuzz/artifacts/$t"
    dirs=("$work")
    [[ -d fuzz/corpus/$t ]] && dirs+=("fuzz/corpus/$t")
    [[ -d fuzz/regressions/$t ]] && dirs+=("fuzz/regressions/$t")
    # The analysis targets (issue 43) read the files their reader's target reads: its
    # seeds are theirs.
    case $t in
        analysis_*) dirs+=("fuzz/corpus/fits_${t#analysis_}") ;;
    esac
    log=fuzz/target/logs/$t.log
    crashes_before=$(find "fuzz/artifacts/$t" -type f | wc -l)
    status=0
    cargo +nightly fuzz run "$t" "${dirs[@]}" -- \
        -max_total_time="$seconds" -timeout=30 -rss_limit_mb=3072 -print_final_stats=1 >"$log" 2>&1 || status=$?
    execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
    corpus=$(find "${dirs[@]}" -type f | wc -l)
    crashes=$(( $(find "fuzz/artifacts/$t" -type f | wc -l) - crashes_before ))
    printf '%-18s %8s %12s %10s %8s\n' "$t" "$seconds" "${execs:-?}" "$corpus" "$crashes"
    if [[ $status -ne 0 ]]; then
        failed+=("$t")
        echo "  $t failed (exit $status); see $log and fuzz/artifacts/$t/" >&2
    fi
done
if [[ ${#failed[@]} -gt 0 ]]; then
    echo "crashed: ${failed[*]}" >&2
    exit 1
fi
