# EVK1000 (STM32F105RC) image. Included by the top-level Makefile; defines `firmware`.
# Owned by the evk1000 board port; placeholder until the port lands.
firmware:
	@echo "firmware: EVK1000 port not yet built" >&2; exit 1
