#!/usr/bin/env bash
# Builds (and optionally runs) the firmware for thumbv7em-none-eabihf with Debian's
# rustc-web toolchain; installs the cross toolchain and QEMU when missing.
#   scripts/firmware.sh install        install the cross toolchain if missing
#   scripts/firmware.sh have           exit 0 if the cross toolchain is there (installs nothing)
#   scripts/firmware.sh build          build; prints the ELF path on the last line
#   scripts/firmware.sh run DIR        run in QEMU with DIR as the semihosting directory
#   scripts/firmware.sh size           flash and RAM use of the release ELF
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
fw="$root/firmware"
target=thumbv7em-none-eabihf
elf="$fw/target/$target/release/dncal-firmware"

have_toolchain() {
  [ -x /usr/bin/cargo ] && [ -x /usr/bin/rustc ] && command -v qemu-system-arm >/dev/null \
    && [ -d /usr/lib/rustlib/src/rust/library/core ] && command -v ld.lld-22 >/dev/null
}

install() {
  if have_toolchain; then return 0; fi
  echo "firmware.sh: installing the cross toolchain (rustc-web cargo-web rust-web-src lld-22 qemu-system-arm)" >&2
  local sudo=""
  [ "$(id -u)" -eq 0 ] || sudo=sudo
  $sudo apt-get update -q >&2
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -q --no-install-recommends rustc-web cargo-web rust-web-src lld-22 qemu-system-arm >&2
  have_toolchain || { echo "firmware.sh: cross toolchain still missing after install" >&2; exit 1; }
}

build() {
  install
  # Debian's cargo and rustc, not rustup's: only they have rust-src for build-std.
  (cd "$fw" && env -u CARGO -u RUSTUP_TOOLCHAIN -u RUSTC_WRAPPER RUSTC=/usr/bin/rustc RUSTC_BOOTSTRAP=1 \
      CARGO_TARGET_THUMBV7EM_NONE_EABIHF_LINKER=ld.lld-22 \
      /usr/bin/cargo build --release --locked -Zbuild-std=core --target "$target" >&2)
  echo "$elf"
}

case "${1:-build}" in
  install) install ;;
  have) have_toolchain ;;
  build) build ;;
  run)
    dir=${2:?usage: firmware.sh run DIR}
    build >/dev/null
    cd "$dir"
    exec qemu-system-arm -cpu cortex-m4 -machine mps2-an386 -nographic \
      -semihosting-config enable=on,target=native -kernel "$elf"
    ;;
  size)
    build >/dev/null
    size=$(command -v llvm-size-22 || command -v llvm-size || command -v size) \
      || { echo "firmware.sh: no llvm-size or size on PATH" >&2; exit 1; }
    "$size" -A "$elf"
    ;;
  *) echo "usage: $0 install|have|build|run DIR|size" >&2; exit 2 ;;
esac
