#!/usr/bin/env bash
# Installs what uwbcal needs on a fresh machine: a venv with the Python package and its
# dev tools, and the arm-none-eabi toolchain (Debian packages) when it is missing.
# Idempotent: a second run only checks.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
if [ ! -x "$VENV/bin/python" ]; then
  python3 -m venv "$VENV"
fi
stamp="$VENV/.uwbcal-installed"
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  "$VENV/bin/pip" install -q --disable-pip-version-check -e '.[dev]'
  touch "$stamp"
fi
if ! command -v arm-none-eabi-gcc >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "bootstrap: installing the arm-none-eabi toolchain (apt)" >&2
    apt-get -o DPkg::Lock::Timeout=300 update -qq
    DEBIAN_FRONTEND=noninteractive apt-get -o DPkg::Lock::Timeout=300 install -y -qq gcc-arm-none-eabi libnewlib-arm-none-eabi binutils-arm-none-eabi >/dev/null
  else
    echo "bootstrap: arm-none-eabi-gcc is missing; install gcc-arm-none-eabi and libnewlib-arm-none-eabi" >&2
    exit 1
  fi
fi
# gdb-multiarch: `uwbcal flash --gdb` and its test against the emulated EVK1000's GDB stub.
# Optional: without it that test skips and says why.
if ! command -v gdb-multiarch >/dev/null 2>&1 && ! command -v arm-none-eabi-gdb >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "bootstrap: installing gdb-multiarch (apt)" >&2
    DEBIAN_FRONTEND=noninteractive apt-get -o DPkg::Lock::Timeout=300 install -y -qq gdb-multiarch >/dev/null \
      || echo "bootstrap: gdb-multiarch could not be installed; the GDB flash test will skip" >&2
  else
    echo "bootstrap: gdb-multiarch is missing (optional: uwbcal flash --gdb)" >&2
  fi
fi
