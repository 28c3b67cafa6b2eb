#!/usr/bin/env bash
# The RTL of hdl/: lint, and the Verilator co-simulation harness. Installs Debian's
# verilator (and iverilog, yosys for the other checks of hdl/) when missing.
#   scripts/hdl.sh install      install the HDL tools if missing
#   scripts/hdl.sh have         exit 0 if Verilator is there (installs nothing)
#   scripts/hdl.sh lint         verilator --lint-only -Wall at every tap count, and iverilog
#   scripts/hdl.sh build TAPS [HEX_DIR]
#                               build the harness for TAPS pixels a clock (its bank 0 from
#                               the $readmemh tables in HEX_DIR, if given); prints its path
#   scripts/hdl.sh soak [PIXELS] the co-simulation on PIXELS pixels (10^8 by default)
#   scripts/hdl.sh synth [DIR]  Yosys synthesis (iCE40 at 1, 2, 4 taps, Xilinx at 1-8) and
#                               nextpnr-ice40 place and route where it fits; a markdown
#                               table on stdout, the tools' logs in DIR (docs/fpga.md)
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
rtl="$root/hdl/rtl/dncal_datapath.v"
rtl_all=("$root/hdl/rtl/dncal_top.v" "$root/hdl/rtl/dncal_regs.v" "$rtl")
out="${CARGO_TARGET_DIR:-$root/target}/hdl"

have_tools() {
  command -v verilator >/dev/null && command -v iverilog >/dev/null && command -v yosys >/dev/null
}

install() {
  if have_tools; then return 0; fi
  echo "hdl.sh: installing verilator, iverilog and yosys (Debian)" >&2
  local sudo=""
  [ "$(id -u)" -eq 0 ] || sudo=sudo
  $sudo apt-get update -q >&2
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -q --no-install-recommends verilator iverilog yosys g++ make >&2
  have_tools || { echo "hdl.sh: the HDL tools are still missing after install" >&2; exit 1; }
}

install_pnr() {
  install
  if command -v nextpnr-ice40 >/dev/null; then return 0; fi
  echo "hdl.sh: installing nextpnr-ice40 and fpga-icestorm (Debian)" >&2
  local sudo=""
  [ "$(id -u)" -eq 0 ] || sudo=sudo
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -q --no-install-recommends nextpnr-ice40 fpga-icestorm >&2 \
    || { $sudo apt-get update -q >&2 && DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -q --no-install-recommends nextpnr-ice40 fpga-icestorm >&2; }
  command -v nextpnr-ice40 >/dev/null || { echo "hdl.sh: nextpnr-ice40 is still missing after install" >&2; exit 1; }
}

lint() {
  install
  for taps in 1 2 4 8; do
    verilator --lint-only -Wall -I"$root/hdl/rtl" -GTAPS=$taps "${rtl_all[@]}"
  done
  verilator --lint-only -Wall -I"$root/hdl/rtl" "$root/hdl/synth/dncal_synth_top.v" "${rtl_all[@]}"
  iverilog -g2005 -Wall -I"$root/hdl/rtl" -o /dev/null "${rtl_all[@]}"
}

build() {
  local taps=${1:?usage: hdl.sh build TAPS [LUT_HEX_DIR]} hex=${2:-}
  case "$taps" in 1|2|4|8) ;; *) echo "hdl.sh: TAPS must be 1, 2, 4 or 8, got $taps" >&2; exit 2 ;; esac
  install
  local dir="$out/taps$taps" params=()
  # With a directory of $readmemh tables (as `dncal fpga-size --lut` writes them), a build
  # of its own whose bank 0 starts with them.
  if [ -n "$hex" ]; then
    dir="$out/taps$taps-hex"
    params=("-GLUT_HEX=\"$hex\"")
  fi
  local bin="$dir/harness"
  # Rebuilt when anything under hdl/, this script or the tables' directory is newer.
  local newer
  newer=$(find "$root/hdl" "$0" ${hex:+"$hex"} -newer "$bin" -type f 2>/dev/null | head -1 || true)
  if [ ! -x "$bin" ] || [ -n "$newer" ] || { [ -n "$hex" ] && ! grep -qF "$hex" "$dir/built-with" 2>/dev/null; }; then
    mkdir -p "$dir"
    verilator --cc --exe --build -O2 -j 2 -Wno-fatal -I"$root/hdl/rtl" -GTAPS="$taps" "${params[@]}" \
      -CFLAGS "-O2 -DTAPS=$taps -I$root/hdl/tb" -Mdir "$dir/obj" -o "$bin" \
      "${rtl_all[@]}" "$root/hdl/tb/harness.cpp" >&2
    echo "$hex" > "$dir/built-with"
  fi
  echo "$bin"
}

# One synthesis: FAMILY (ice40 or xilinx), TAPS, CODE_BITS, FIFO_AW, MAX_LATENCY; the cell
# counts as `name count` lines in DIR/FAMILY-tTAPS-cCODE.stat.
synth_one() {
  local family=$1 taps=$2 code=$3 fifo=$4 lat=$5 dir=$6
  local tag="$family-t$taps-c$code"
  local cmd="synth_ice40 -top dncal_synth_top -json $dir/$tag.json"
  [ "$family" = xilinx ] && cmd="synth_xilinx -top dncal_synth_top -family xc7"
  /usr/bin/time -f "%e" -o "$dir/$tag.seconds" yosys -q -l "$dir/$tag.log" -p "read_verilog -I$root/hdl/rtl ${rtl_all[*]} $root/hdl/synth/dncal_synth_top.v; chparam -set TAPS $taps -set CODE_BITS $code -set FIFO_AW $fifo -set MAX_LATENCY $lat dncal_synth_top; $cmd; tee -q -o $dir/$tag.stat stat" >/dev/null
}

# Cells of a kind (a regular expression) in a stat file, summed.
cells() {
  awk -v re="$2" '$1 ~ "^(" re ")$" { n += $2 } END { print n + 0 }' "$1"
}

synth() {
  install_pnr
  local dir=${1:-$out/synth}
  mkdir -p "$dir"
  echo "| part | taps | code bits | FIFO | memory latency | LUTs | flip-flops | block RAMs | DSPs | carries | Yosys s | place and route |"
  echo "|---|---|---|---|---|---|---|---|---|---|---|---|"
  # (Not 8 taps on iCE40: 4 taps already need twice the largest part's LUTs, and 8 took
  # Yosys more than ten minutes.)
  for taps in 1 2 4; do
    synth_one ice40 "$taps" 8 4 8 "$dir"
    local s="$dir/ice40-t$taps-c8.stat" pnr="not run: more LUTs than the HX8K's 7,680"
    local luts
    luts=$(cells "$s" "SB_LUT4")
    if [ "$luts" -le 7680 ]; then
      for dev in "hx8k --package ct256" "up5k --package sg48"; do
        # shellcheck disable=SC2086
        if nextpnr-ice40 --$dev --json "$dir/ice40-t$taps-c8.json" --freq 20 --seed 1 --timing-allow-fail --pcf-allow-unconstrained >"$dir/pnr-t$taps-${dev%% *}.log" 2>&1; then
          # (The routed report, the last of each clock's: the pixel clock, then the
          # configuration clock.)
          local log="$dir/pnr-t$taps-${dev%% *}.log" fmax
          fmax=$(grep -o "Max frequency for clock *'[a-z_]*" "$log" | tail -2 | sed "s/.*'//" | while read -r c; do
            printf '%s %s MHz, ' "$c" "$(grep -o "Max frequency for clock *'$c[^:]*: [0-9.]* MHz" "$log" | tail -1 | grep -o '[0-9.]* MHz$' | cut -d' ' -f1)"; done)
          pnr="$pnr; ${dev%% *}: ${fmax}$(grep -o 'ICESTORM_LC: *[0-9]*/ *[0-9]*' "$log" | tail -1 | tr -s ' ') LCs"
        else
          pnr="$pnr; ${dev%% *}: does not fit ($(grep -m1 -o 'ERROR: .*' "$dir/pnr-t$taps-${dev%% *}.log" | cut -c1-80))"
        fi
      done
      pnr=${pnr#not run: more LUTs than the HX8K*; }
    fi
    echo "| iCE40 | $taps | 8 | 16 | 8 | $luts | $(cells "$s" 'SB_DFF.*') | $(cells "$s" 'SB_RAM40_4K') | $(cells "$s" 'SB_MAC16') | $(cells "$s" 'SB_CARRY') | $(cat "$dir/ice40-t$taps-c8.seconds") | $pnr |"
  done
  for taps in 1 2 4 8; do
    synth_one xilinx "$taps" 12 4 8 "$dir"
    local s="$dir/xilinx-t$taps-c12.stat"
    echo "| Xilinx 7-series | $taps | 12 | 16 | 8 | $(cells "$s" 'LUT[1-6]') | $(cells "$s" 'FD[CPRSE]*') | $(cells "$s" 'RAMB36E1') x 36k + $(cells "$s" 'RAMB18E1') x 18k | $(cells "$s" 'DSP48E1') | $(cells "$s" 'CARRY4') | $(cat "$dir/xilinx-t$taps-c12.seconds") | not run (no open place and route for it) |"
  done
}

case "${1:-}" in
  install) install ;;
  have) command -v verilator >/dev/null ;;
  lint) lint ;;
  build) build "${2:-}" "${3:-}" ;;
  synth) synth "${2:-}" ;;
  soak)
    install
    cd "$root"
    DNCAL_REQUIRE_HDL=1 DNCAL_RTL_SOAK_PIXELS="${2:-100000000}" exec cargo test --profile checked --locked \
      -p dncal-fpga-model --test rtl_cosim -- --ignored --nocapture soak_the_rtl
    ;;
  *) echo "usage: $0 install|have|lint|build TAPS|synth [DIR]|soak [PIXELS]" >&2; exit 2 ;;
esac
