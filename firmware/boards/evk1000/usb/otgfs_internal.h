/* Internal to the OTG FS driver (otgfs.c: core, bus events, data endpoints; otgfs_ep0.c: EP0
 * control transfers and the standard requests). Not for the class: it uses otgfs.h. */
#ifndef EVK1000_USB_OTGFS_INTERNAL_H
#define EVK1000_USB_OTGFS_INTERNAL_H

#include "otgfs.h"

enum ep0_stage { EP0_IDLE = 0, EP0_DATA_IN, EP0_DATA_OUT, EP0_STATUS_IN, EP0_STATUS_OUT };

struct otgfs_state {
    enum usbd_state state;
    bool suspended;
    uint8_t config;
    uint32_t bus_resets;
    /* EP0 */
    uint32_t setup_words[2];
    struct usbd_setup req;
    enum ep0_stage stage;
    const uint8_t *in_ptr;
    uint16_t in_left;
    bool in_zlp;
    uint8_t out_buf[USBD_EP0_MPS];
    uint16_t out_len;
    uint8_t reply[2];
    /* IN endpoints 1 and 2 */
    volatile bool in_busy[3];
    volatile bool in_zlp_after[3];
    uint16_t in_len[3];
    bool halted_in[3], halted_out[3];
    bool out_paused;
};

/* The driver's one state (otgfs.c). */
extern struct otgfs_state otg;

/* otgfs.c */
bool otgfs_wait_bits(uint32_t reg, uint32_t mask, uint32_t value);
void otgfs_fifo_write(uint8_t ep, const uint8_t *p, size_t len);
void otgfs_endpoints_open(bool on);

/* otgfs_ep0.c: called from the interrupt handler and the bus reset */
void otgfs_ep0_out_arm(void);
void otgfs_ep0_setup(void);
void otgfs_ep0_in_done(void);
void otgfs_ep0_out_done(void);

#endif
