#!/usr/bin/env bash
# Mutation testing (cargo-mutants): each mutant is a small change to the code (an
# operator flipped, a function returning a default, a condition negated); a mutant the
# tests do not notice ("missed") is code whose result no test checks.
#
#   scripts/mutants.sh core   the correction core (accumulate, lut, image, banks,
#                             histogram, noise) against the core's tests and the FPGA
#                             model's (which check the model against naive sums)
#   scripts/mutants.sh host   a uniform sample (MUTANTS_SHARD, default every 400th) of
#                             the mutants of analyses/{diagnose/, flatten.rs,
#                             quantization/, kcor/}, analyses/adc.rs and
#                             model/camera/calibration.rs against the
#                             host's library tests (the CLI tests run whole commands)
#   scripts/mutants.sh FILE.. those files, tested by their own package
#
# Reports go to target/mutants/<name>/mutants.out (missed.txt, caught.txt, ...); the
# survival rates and the equivalent mutants, with the reason each changes no result, are
# in docs/testing.md. Installs cargo-mutants (from crates.io) when missing. Runs from a
# fresh clone; a copy of the tree is mutated, never the working tree.
set -euo pipefail
cd "$(dirname "$0")/.."

VERSION=27.1.0
if ! cargo mutants --version 2>/dev/null | grep -q "$VERSION"; then
    echo "installing cargo-mutants $VERSION" >&2
    cargo install cargo-mutants --locked --version "$VERSION"
fi

JOBS=${MUTANTS_JOBS:-2}
run() {
    local name=$1
    shift
    echo "== mutants: $name" >&2
    mkdir -p "target/mutants/$name"
    # Exit 2 means missed mutants: reported, not an error of the script.
    cargo mutants --no-shuffle -j "$JOBS" --timeout 600 --build-timeout 1800 -o "target/mutants/$name" "$@" || {
        local rc=$?
        [ "$rc" -eq 2 ] || [ "$rc" -eq 3 ] || return "$rc"
    }
    report "target/mutants/$name/mutants.out" "$name"
}

# The counts of a report folder, and the missed mutants.
report() {
    local out=$1 name=$2
    printf '%s: caught %s, missed %s, timeout %s, unviable %s\n' "$name" \
        "$(wc -l < "$out/caught.txt")" "$(wc -l < "$out/missed.txt")" \
        "$(wc -l < "$out/timeout.txt")" "$(wc -l < "$out/unviable.txt")"
    if [ -s "$out/missed.txt" ]; then
        echo "missed:"
        sed 's/^/  /' "$out/missed.txt"
    fi
}

# As `run`, in place in the current directory (one job: the tree is mutated), the report
# in $OUT.
run_in_place() {
    echo "== mutants in place: $PWD -> $OUT" >&2
    mkdir -p "$OUT"
    cargo mutants --in-place --no-shuffle --timeout 300 --build-timeout 1800 -o "$OUT" "$@" || {
        local rc=$?
        [ "$rc" -eq 2 ] || [ "$rc" -eq 3 ] || return "$rc"
    }
    report "$OUT/mutants.out" host
}

case "${1:-core}" in
core)
    files=()
    for f in accumulate lut image banks histogram noise; do files+=(-f "core/src/$f.rs"); done
    run core -p dncal-core "${files[@]}" --test-package dncal-core --test-package dncal-fpga-model
    ;;
host)
    # About 3,300 mutants. In cargo-mutants' copy of the tree every mutant rebuilt the
    # host crate's test targets from a cold start of the copy (about 110 s each, 614 s for
    # the baseline), so this mode mutates in place a worktree of HEAD kept under
    # target/mutants-tree, whose own warm target folder makes a mutant an incremental
    # rebuild of the library's tests (about 50 s) plus the tests (about a minute); `--lib`
    # goes to both of cargo-mutants' cargo commands (with --cargo-test-arg only the test
    # run had it, and the build built every integration test too: 99 s). What is
    # tested is the committed HEAD, never the working tree. Still two days for all:
    # a uniform sample instead, every K-th mutant in a fixed order (MUTANTS_SHARD=0/K,
    # default 0/400; 1/400 is the next sample, and so on).
    tree=target/mutants-tree
    if [ ! -e "$tree/.git" ]; then
        git worktree add --detach "$tree" HEAD
    fi
    git -C "$tree" diff --quiet || { echo "$tree has changes (an interrupted run?): git -C $tree checkout -- ." >&2; exit 1; }
    git -C "$tree" checkout -q --detach "$(git rev-parse HEAD)"
    files=()
    for f in 'analyses/diagnose/**' analyses/flatten.rs analyses/quantization/mod.rs analyses/kcor/mod.rs analyses/adc.rs model/camera/calibration.rs; do files+=(-f "host-sim/src/$f"); done
    shard=${MUTANTS_SHARD:-0/400}
    # diagnose/run.rs (the command's glue: sniffing, spill policy, the HTML report) came
    # under diagnose/ on 2026-11-28 and is left out, so the samples stay the same set.
    files+=(-e host-sim/src/analyses/diagnose/run.rs)
    (cd "$tree" && OUT="$PWD/../mutants/host-${shard//\//-}" run_in_place -p dncal-host "${files[@]}" \
        --test-workspace=false --cargo-arg=--lib --shard "$shard" --sharding round-robin)
    ;;
*)
    files=()
    for f in "$@"; do files+=(-f "$f"); done
    run files "${files[@]}" --test-workspace=false
    ;;
esac
