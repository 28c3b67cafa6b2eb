#!/usr/bin/env bash
# The RTL of hdl/: lint, and the Verilator co-simulation harness. Installs Debian's
# verilator (and iverilog, yosys for the other checks of hdl/) when missing.
#   scripts/hdl.sh install      install the HDL tools if missing
#   scripts/hdl.sh have         exit 0 if Verilator is there (installs nothing)
#   scripts/hdl.sh lint         verilator --lint-only -Wall at every tap count, and iverilog
#   scripts/hdl.sh build TAPS   build the harness for TAPS pixels a clock; prints its path
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
rtl="$root/hdl/rtl/dncal_datapath.v"
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

lint() {
  install
  for taps in 1 2 4 8; do
    verilator --lint-only -Wall -I"$root/hdl/rtl" -GTAPS=$taps "$rtl"
  done
  iverilog -g2005 -Wall -I"$root/hdl/rtl" -o /dev/null "$rtl"
}

build() {
  local taps=${1:?usage: hdl.sh build TAPS}
  case "$taps" in 1|2|4|8) ;; *) echo "hdl.sh: TAPS must be 1, 2, 4 or 8, got $taps" >&2; exit 2 ;; esac
  install
  local dir="$out/taps$taps"
  local bin="$dir/harness"
  # Rebuilt when the RTL, the harness or this script is newer than the binary.
  local newer
  newer=$(find "$root/hdl" "$0" -newer "$bin" -type f 2>/dev/null | head -1 || true)
  if [ ! -x "$bin" ] || [ -n "$newer" ]; then
    mkdir -p "$dir"
    verilator --cc --exe --build -O2 -j 2 -Wno-fatal -I"$root/hdl/rtl" -GTAPS="$taps" \
      -CFLAGS "-O2 -DTAPS=$taps -I$root/hdl/tb" -Mdir "$dir/obj" -o "$bin" \
      "$rtl" "$root/hdl/tb/harness.cpp" >&2
  fi
  echo "$bin"
}

case "${1:-}" in
  install) install ;;
  have) command -v verilator >/dev/null ;;
  lint) lint ;;
  build) build "${2:-}" ;;
  *) echo "usage: $0 install|have|lint|build TAPS" >&2; exit 2 ;;
esac
