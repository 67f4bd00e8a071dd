/* A small device-mode driver for the STM32F105's USB OTG FS core (RM0008 chapter 28), made
 * for exactly one configuration: EP0 control, one bulk IN/OUT pair and one interrupt IN
 * endpoint (a CDC-ACM function, usb/cdc_acm.c). Interrupt driven (OTG_FS_IRQHandler).
 *
 * The driver owns the core, EP0 and the standard requests of USB 2.0 chapter 9; the class
 * (cdc_acm.c) owns the descriptors, the class requests and the data, through the usbd_class_*
 * callbacks below.
 */
#ifndef EVK1000_USB_OTGFS_H
#define EVK1000_USB_OTGFS_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#define USBD_EP0_MPS 64u
#define USBD_EP_DATA 1u      /* bulk IN 0x81 and bulk OUT 0x01 */
#define USBD_EP_NOTIFY 2u    /* interrupt IN 0x82 */
#define USBD_DATA_MPS 64u    /* full-speed bulk maximum */
#define USBD_NOTIFY_MPS 16u
/* Largest bulk IN transfer started at once: the EP1 TX FIFO holds it whole (words). */
#define USBD_DATA_TX_MAX 512u

/* One SETUP packet (USB 2.0 9.3), fields in host order. */
struct usbd_setup {
    uint8_t bmRequestType;
    uint8_t bRequest;
    uint16_t wValue;
    uint16_t wIndex;
    uint16_t wLength;
};

enum usbd_state { USBD_DETACHED = 0, USBD_DEFAULT, USBD_ADDRESSED, USBD_CONFIGURED };

/* Clocks, core reset and init, FIFO sizing, then the pull-up (connect). Returns 0, or -1 if
 * a wait of the core reset ran out (the link then stays down; nothing hangs). */
int usbd_init(void);
void usbd_irq(void);
enum usbd_state usbd_state(void);
bool usbd_suspended(void);
uint32_t usbd_bus_resets(void);

/* Bulk / interrupt IN: start a transfer of len bytes (<= USBD_DATA_TX_MAX) on ep, copied to
 * its TX FIFO now. A bulk transfer whose length is a multiple of 64 is followed by a
 * zero-length packet. Returns false if the endpoint is busy or not configured. Interrupt
 * safe (called from the main loop and from the class callbacks in the handler). */
bool usbd_in_start(uint8_t ep, const uint8_t *data, size_t len);
bool usbd_in_busy(uint8_t ep);
/* Nesting critical section against the USB interrupt (PRIMASK save / restore). */
uint32_t usbd_irq_save(void);
void usbd_irq_restore(uint32_t primask);
/* Bulk OUT: accept one more packet (the class calls it when it has room for 64 bytes). */
void usbd_out_arm(uint8_t ep);

/* ---- provided by the class ----------------------------------------------------------- */
/* Descriptor of type (USB 2.0 table 9-5) and index, or NULL (the request is STALLed). */
const uint8_t *usbd_class_descriptor(uint8_t type, uint8_t index, uint16_t *len);
/* A class or vendor request. For IN requests set *reply and *len (len is clipped to wLength);
 * for OUT requests with data, the data comes later through usbd_class_out_data. Return 0 to
 * accept, -1 to STALL. */
int usbd_class_setup(const struct usbd_setup *s, const uint8_t **reply, uint16_t *len);
void usbd_class_out_data(const struct usbd_setup *s, const uint8_t *data, uint16_t len);
/* SET_CONFIGURATION (true) / reset, SET_CONFIGURATION 0, suspend of the bus (false). */
void usbd_class_configured(bool on);
/* Bulk OUT bytes of one packet; return true if there is room to arm for another. */
bool usbd_class_rx(const uint8_t *data, size_t len);
/* The bulk IN transfer on ep ended: all of it was sent (done), or a bus reset or
 * deconfiguration cut it after `sent` bytes the host acknowledged (the rest was flushed). */
void usbd_class_in_done(uint8_t ep, size_t sent);

#endif
