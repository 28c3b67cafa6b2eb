#!/usr/bin/env bash
# Mutation testing (cargo-mutants): each mutant is a small change to the code (an
# operator flipped, a function returning a default, a condition negated); a mutant the
# tests do not notice ("missed") is code whose result no test checks.
#
#   scripts/mutants.sh core   the correction core (accumulate, lut, image, banks,
#                             histogram, noise) against the core's tests and the FPGA
#                             model's (which check the model against naive sums)
#   scripts/mutants.sh host   a uniform sample (MUTANTS_SHARD, default every 400th) of
#                             the mutants of diagnose/, flatten.rs, quantization.rs,
#                             kcor.rs, commands/adc.rs, camera/calibration.rs against the
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
    local out="target/mutants/$name/mutants.out"
    printf '%s: caught %s, missed %s, timeout %s, unviable %s\n' "$name" \
        "$(wc -l < "$out/caught.txt")" "$(wc -l < "$out/missed.txt")" \
        "$(wc -l < "$out/timeout.txt")" "$(wc -l < "$out/unviable.txt")"
    if [ -s "$out/missed.txt" ]; then
        echo "missed:"
        sed 's/^/  /' "$out/missed.txt"
    fi
}

case "${1:-core}" in
core)
    files=()
    for f in accumulate lut image banks histogram noise; do files+=(-f "core/src/$f.rs"); done
    run core -p dncal-core "${files[@]}" --test-package dncal-core --test-package dncal-fpga-model
    ;;
host)
    # About 3,200 mutants, each a rebuild of the host crate (1-3 min here) and its library
    # tests (about a minute): days on two cores. A uniform sample instead: every K-th
    # mutant in a fixed order (MUTANTS_SHARD=0/K, default 0/400; 1/400 is the next
    # sample, and so on).
    files=()
    for f in 'diagnose/**' flatten.rs quantization.rs kcor.rs commands/adc.rs camera/calibration.rs; do files+=(-f "host-sim/src/$f"); done
    # (Copying the build folder with the tree does not help: cargo rebuilt everything in the
    # copy, 614 s against 636 s without it.)
    run host -p dncal-host "${files[@]}" --test-workspace=false --cargo-test-arg=--lib \
        --shard "${MUTANTS_SHARD:-0/400}" --sharding round-robin
    ;;
*)
    files=()
    for f in "$@"; do files+=(-f "$f"); done
    run files "${files[@]}" --test-workspace=false
    ;;
esac
