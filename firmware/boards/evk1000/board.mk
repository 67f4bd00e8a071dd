# EVK1000 (STM32F105RC, Cortex-M3) image. Included by the top-level Makefile; defines
# `firmware`. Uses the top-level CSTD CWARN CVER CINC FW_SRC BUILD, so the image is built
# with exactly the warnings (-Werror) of the native build, and every C file added to
# firmware/core or firmware/dw1000 is picked up through FW_SRC's wildcard.

ARM_PREFIX ?= arm-none-eabi-
ARM_CC := $(ARM_PREFIX)gcc
ARM_OBJCOPY := $(ARM_PREFIX)objcopy
ARM_SIZE := $(ARM_PREFIX)size
ARM_NM := $(ARM_PREFIX)nm

EVK_DIR := firmware/boards/evk1000
# Host link: LINK=usb (default: USB CDC-ACM on OTG FS, the EVK1000's PC port, usb/) or
# LINK=usart (USART1 on PA9/PA10, for boards wired that way; docs/EVK1000.md "Host link").
LINK ?= usb
ifeq ($(filter usb usart,$(LINK)),)
$(error LINK must be usb or usart, not '$(LINK)')
endif
EVK_COMMON_SRC := $(filter-out $(EVK_DIR)/link_usart.c,$(sort $(wildcard $(EVK_DIR)/*.c)))
EVK_LINK_SRC_usb := $(sort $(wildcard $(EVK_DIR)/usb/*.c))
EVK_LINK_SRC_usart := $(EVK_DIR)/link_usart.c
EVK_SRC := $(EVK_COMMON_SRC) $(EVK_LINK_SRC_$(LINK))
# The USB image (the default, what `uwbcal flash` writes) in build/evk1000/, the USART one in
# build/evk1000-usart/: both can exist side by side.
EVK_OUT := $(BUILD)/evk1000$(if $(filter usart,$(LINK)),-usart,)
EVK_IMG := $(EVK_OUT)/uwbcal-evk1000
EVK_OBJ := $(patsubst %.c,$(EVK_OUT)/obj/%.o,$(FW_SRC) $(EVK_SRC))
EVK_LD := $(EVK_DIR)/evk1000.ld

# Bars of issue 2 (bytes): flash = text + data, RAM = data + bss (static; the stack
# reservation is printed separately).
EVK_FLASH_BAR ?= 65536
EVK_RAM_BAR ?= 16384

ARM_ARCH := -mcpu=cortex-m3 -mthumb -mfloat-abi=soft
ARM_CFLAGS := $(ARM_ARCH) -Os -g3 -ffunction-sections -fdata-sections -fno-common \
  --specs=nano.specs -I$(EVK_DIR) -I$(EVK_DIR)/usb
ARM_LDFLAGS := $(ARM_ARCH) --specs=nano.specs -nostartfiles -L$(EVK_DIR) -T$(EVK_LD) \
  -Wl,--gc-sections -Wl,--no-warn-rwx-segments -Wl,--fatal-warnings -Wl,--print-memory-usage

# Symbols whose presence means dynamic allocation (or a syscall stub) was pulled in.
EVK_FORBIDDEN := malloc free calloc realloc _malloc_r _free_r _calloc_r _realloc_r _sbrk _sbrk_r

.PHONY: firmware evk1000-toolchain
firmware: $(EVK_IMG).elf $(EVK_IMG).bin $(EVK_IMG).hex
	@bash $(EVK_DIR)/size.sh $(EVK_IMG).elf $(EVK_FLASH_BAR) $(EVK_RAM_BAR) $(ARM_SIZE) $(ARM_NM)

evk1000-toolchain:
	@command -v $(ARM_CC) >/dev/null 2>&1 || { echo "firmware: $(ARM_CC) not found;" \
	  "run tools/bootstrap.sh or apt-get install gcc-arm-none-eabi libnewlib-arm-none-eabi" >&2; exit 1; }

# Rebuild when the version flags change (the git hash is baked into GET_INFO).
$(EVK_OUT)/cflags.txt: FORCE_EVK_FLAGS
	@mkdir -p $(@D)
	@echo '$(CSTD) $(CWARN) $(CVER) $(CINC) $(ARM_CFLAGS) LINK=$(LINK)' | cmp -s - $@ || \
	  echo '$(CSTD) $(CWARN) $(CVER) $(CINC) $(ARM_CFLAGS) LINK=$(LINK)' > $@
.PHONY: FORCE_EVK_FLAGS
FORCE_EVK_FLAGS:

$(EVK_OUT)/obj/%.o: %.c $(EVK_OUT)/cflags.txt | evk1000-toolchain
	@mkdir -p $(@D)
	$(ARM_CC) $(CSTD) $(CWARN) $(CVER) $(CINC) $(ARM_CFLAGS) -MMD -MP -c -o $@ $<

$(EVK_IMG).elf: $(EVK_OBJ) $(EVK_LD) $(EVK_DIR)/evk1000_sections.ld $(EVK_OUT)/cflags.txt
	@mkdir -p $(@D)
	$(ARM_CC) $(ARM_LDFLAGS) -Wl,-Map=$(EVK_IMG).map -o $@ $(EVK_OBJ) -lm
	@bad=$$($(ARM_NM) $@ | awk '{ print $$NF }' | grep -xE '$(subst $(eval) ,|,$(EVK_FORBIDDEN))' || true); \
	if [ -n "$$bad" ]; then echo "firmware: dynamic allocation pulled in:" $$bad >&2; rm -f $@; exit 1; fi

$(EVK_IMG).bin: $(EVK_IMG).elf
	$(ARM_OBJCOPY) -O binary $< $@
$(EVK_IMG).hex: $(EVK_IMG).elf
	$(ARM_OBJCOPY) -O ihex $< $@

-include $(EVK_OBJ:.o=.d)


# --- HOST-ONLY: the USB link and the station core as a shared library --------------------
# usb/otgfs.c and usb/cdc_acm.c built with -DOTG_HOSTED for the host, with the station core,
# so tests drive the real driver against the Python OTG FS model (usb/hosted/hosted_board.c,
# host/uwbcal/evk1000/usbhosted.py). UBSan on; ASan cannot be loaded into a Python process.
USBH_DIR := $(EVK_DIR)/usb
USBH_LIB := $(BUILD)/usbhosted/libevkusb.so
USBH_SRC := $(FW_SRC) $(USBH_DIR)/otgfs.c $(USBH_DIR)/otgfs_ep0.c $(USBH_DIR)/cdc_acm.c $(USBH_DIR)/hosted/hosted_board.c \
  firmware/boards/native/flash.c firmware/boards/native/radio_tunnel.c firmware/boards/native/signals.c
.PHONY: usbhosted
usbhosted: $(USBH_LIB)
$(USBH_LIB): $(USBH_SRC) $(FW_HDR) $(wildcard $(USBH_DIR)/*.h) VERSION $(BUILD)/native-flags.txt
	@mkdir -p $(@D)
	$(CC) $(CSTD) $(CWARN) $(CVER) $(CINC) -I$(EVK_DIR) -I$(USBH_DIR) -Ifirmware/boards/native -DOTG_HOSTED \
	  -O1 -g -fPIC -shared -fsanitize=undefined -fno-sanitize-recover=all -Wl,--no-undefined \
	  -o $@ $(USBH_SRC) -lm
