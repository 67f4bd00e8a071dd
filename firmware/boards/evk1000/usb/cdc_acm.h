/* CDC-ACM function of the EVK1000's USB link (cdc_acm.c): what the rest of the board and the
 * host-side test harness may ask it. The host link itself is board.h's board_link_*. */
#ifndef EVK1000_USB_CDC_ACM_H
#define EVK1000_USB_CDC_ACM_H

#include <stdint.h>

uint32_t cdc_tx_dropped(void);  /* bytes board_link_write could not send (no host, timeout) */
uint16_t cdc_line_state(void);
uint32_t cdc_tx_queued(void);   /* bytes in the TX ring not yet acknowledged by the host */  /* SET_CONTROL_LINE_STATE: bit 0 DTR, bit 1 RTS */

#endif
