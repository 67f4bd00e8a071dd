#!/usr/bin/env bash
# Prints the flash and RAM use of an STM32 image against the bars; fails when over.
# usage: size.sh ELF FLASH_BAR RAM_BAR [SIZE_TOOL NM_TOOL]
set -euo pipefail
elf=$1 flash_bar=$2 ram_bar=$3 size_tool=${4:-arm-none-eabi-size} nm_tool=${5:-arm-none-eabi-nm}
# Per section (size -A): flash = vectors + text + exidx + data image; RAM = data + bss +
# noinit. The stack reservation is a NOLOAD section of its own, reported apart.
sections=$("$size_tool" -A "$elf")
sum() { awk -v re="$1" '$1 ~ re { s += $2 } END { print s + 0 }' <<<"$sections"; }
data=$(sum '^\.data$')
flash=$(( $(sum '^\.(isr_vector|text|ARM\.exidx)$') + data ))
ram=$(( data + $(sum '^\.(bss|noinit)$') ))
stack=$(sum '^\.stack_reserve$')
verdict() { if [ "$1" -lt "$2" ]; then echo ok; else echo OVER; fi; }
kb() { awk -v b="$1" 'BEGIN { printf "%.1f", b / 1024 }'; }
echo "image: ${elf%.elf}.{elf,bin,hex,map}"
printf '  flash (text+data): %6d bytes (%5s KB), bar < %d bytes: %s\n' \
  "$flash" "$(kb "$flash")" "$flash_bar" "$(verdict "$flash" "$flash_bar")"
printf '  RAM   (data+bss):  %6d bytes (%5s KB), bar < %d bytes: %s\n' \
  "$ram" "$(kb "$ram")" "$ram_bar" "$(verdict "$ram" "$ram_bar")"
printf '  stack reserved:    %6d bytes above data+bss (link fails if it does not fit)\n' "$stack"
if [ "$flash" -ge "$flash_bar" ] || [ "$ram" -ge "$ram_bar" ]; then
  echo "firmware: over the size bars" >&2
  exit 1
fi
