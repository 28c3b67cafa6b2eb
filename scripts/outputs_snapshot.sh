#!/usr/bin/env bash
# Every output a user sees, written by one dncal binary into one folder, so that two
# builds can be compared with scripts/outputs_compare.py (issue 40: a redesign leaves the
# outputs as they were).
#
#   scripts/outputs_snapshot.sh BINARY DIR
#
# Runs the demo, a diagnose of each input kind (histogram set, linearity set, EMVA 1288
# descriptor: simulated and the real CCD set in ../shared), the K-Cor round trip
# (import, export, inspect, kcor-model on the imported image), the characterization
# commands, and a few refusals (stderr and exit code kept). Each command's stdout goes to
# NAME.out, its stderr to NAME.err (stage lines are off: -q) and its exit code to NAME.rc.
# About two minutes with a debug build.
set -uo pipefail
if [ $# -ne 2 ]; then
    echo "usage: $0 BINARY DIR" >&2
    exit 2
fi
bin=$(realpath "$1")
out=$2
shared=$(realpath "$(dirname "$0")/../../shared" 2>/dev/null || true)
if [ ! -d "$shared/data" ]; then
    echo "$0: ../shared/data not found beside the repository" >&2
    exit 2
fi
rm -rf "$out"
mkdir -p "$out"
cd "$out"
# Where the outputs were written: outputs_compare.py reads this path in them as "<dir>".
pwd >.snapshot-root
# The binary under one name in every snapshot: the FITS files' HISTORY records the
# command line as run, and two binaries compared must not differ by their paths.
ln -s "$bin" .dncal
bin=./.dncal

# run NAME ARGS...: one command, its stdout, stderr and exit code kept.
run() {
    local name=$1
    shift
    "$bin" -q "$@" >"$name.out" 2>"$name.err"
    echo $? >"$name.rc"
}

kcor=$shared/data/kcor-luts/Photonfocus_MV-D1024E_08888_adc{adc}_20131106.bin
emva=$shared/data/emva1288-ccd-12bit/EMVA1288_Data.txt

run demo demo -o demo --json
run sim-hist simulate histograms -o hist.fits --first-ramp 40 --last-ramp 41 \
    --pixels-per-adc 4096 --frames-per-level 50 --json
run sim-lin simulate linearity -o lin.fits --levels 21 --frames 64 --roi 64x64+480+480 --json
run diag-hist diagnose hist.fits -o diag-hist --json
run diag-lin diagnose lin.fits -o diag-lin --json
run diag-emva diagnose "$emva" -o diag-emva --json
run diag-both diagnose hist.fits lin.fits -o diag-both --json
run emva emva "$emva" -o emva --json
run linearity linearity lin.fits -o linearity --json
run adc-hist adc --hist hist.fits -o adc-hist --json
run adc-sim adc -o adc-sim --first-ramp 40 --last-ramp 41 --pixels-per-adc 4096 \
    --frames-per-level 50 --json
run adc-kcor adc --from-luts "$kcor" -o adc-kcor --json
mkdir -p lut kc
run lut-build lut build hist.fits -o lut/h --json
run inspect-fits lut inspect lut/h.fits --json
run inspect-bin lut inspect lut/h.bin --json
run inspect-text lut inspect lut/h.fits --table
run kc-import lut import --kcor "$kcor" -o kc/k --json
run kc-export lut export kc/k.fits --format kcor -o kc/exp --json
for a in 0 1 2 3; do
    cmp "kc/exp_adc$a.bin" "${kcor//\{adc\}/$a}" >kc/roundtrip_adc$a.cmp 2>&1
    echo $? >>kc/roundtrip_adc$a.cmp
done
run kc-inspect lut inspect kc/k.bin
run kcor-model kcor-model --lut kc/k.bin --steps 20 -o kcor-model --json
run kcor-model-sim kcor-model --steps 20 --realizations 2 --json
run stream stream --hist hist.fits --frames 4 --roi 64x32+0+0 --json
run stream-fpga stream --engine fpga --frames 2 --roi 32x16+0+0 --json
run quant quantization --sigma 0.3 --bias 0.01 --samples 10000 --figure quant.png --json
run fpga-size fpga-size --json

# Refusals: the message and the exit code are outputs too.
printf 'SIMPLE  = F' >bad.fits
run bad-missing lut build no-such-file.fits -o lut/x
run bad-fits diagnose bad.fits
run bad-lin linearity hist.fits
run bad-inspect lut inspect bad.fits
run bad-kcor lut import --kcor bad.fits bad.fits bad.fits -o kc/x
run bad-stream stream --frames 0
run bad-roi stream --roi 4096x4096+0+0
run bad-config demo --config bad.fits -o d2
run bad-emva emva bad.fits
exit 0
