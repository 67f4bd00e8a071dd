"""uwbcal: DW1000 clock drift correction and power self-calibration (Sidorenko et al.)."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("uwbcal")
except PackageNotFoundError:  # running from a source tree without an install
    __version__ = "0+unknown"
