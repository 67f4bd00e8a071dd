#!/usr/bin/env bash
# Installs what uwbcal needs on a fresh machine: a venv with the Python package and its
# dev tools, and the arm-none-eabi toolchain (Debian packages) when it is missing.
# Idempotent: a second run only checks.
# `tools/bootstrap.sh --fuzz` also installs clang (libFuzzer) when it is missing (make fuzz).
set -euo pipefail
cd "$(dirname "$0")/.."
apt_install() {  # apt_install WHAT PACKAGE...: as root with apt, else say what to install
  local what=$1; shift
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "bootstrap: installing $what (apt)" >&2
    apt-get -o DPkg::Lock::Timeout=300 update -qq
    DEBIAN_FRONTEND=noninteractive apt-get -o DPkg::Lock::Timeout=300 install -y -qq "$@" >/dev/null
  else
    echo "bootstrap: $what is missing; install $*" >&2
    exit 1
  fi
}
if [ "${1:-}" = "--fuzz" ]; then
  command -v clang >/dev/null 2>&1 || apt_install "clang (libFuzzer)" clang llvm
  command -v llvm-profdata >/dev/null 2>&1 || apt_install "llvm (coverage tools)" llvm
  exit 0
fi
VENV=${VENV:-.venv}
if [ ! -x "$VENV/bin/python" ]; then
  python3 -m venv "$VENV"
fi
stamp="$VENV/.uwbcal-installed"
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  "$VENV/bin/pip" install -q --disable-pip-version-check -e '.[dev]'
  touch "$stamp"
fi
command -v arm-none-eabi-gcc >/dev/null 2>&1 ||
  apt_install "the arm-none-eabi toolchain" gcc-arm-none-eabi libnewlib-arm-none-eabi binutils-arm-none-eabi
# gdb-multiarch: `uwbcal flash --gdb` and its test against the emulated EVK1000's GDB stub.
# Optional: without it that test skips and says why.
if ! command -v gdb-multiarch >/dev/null 2>&1 && ! command -v arm-none-eabi-gdb >/dev/null 2>&1; then
  (apt_install "gdb-multiarch (optional: uwbcal flash --gdb)" gdb-multiarch) ||
    echo "bootstrap: gdb-multiarch could not be installed; the GDB flash test will skip" >&2
fi
