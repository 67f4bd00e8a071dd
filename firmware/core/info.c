/* Core request handlers: PING, GET_INFO, RESET. */
#include <string.h>

#include "app.h"
#include "board.h"
#include "dw1000_ops.h"
#include "proto_gen.h"

#ifndef UWBCAL_FW_VERSION
#define UWBCAL_FW_VERSION "0.0.0"
#endif
#ifndef UWBCAL_GIT_HASH
#define UWBCAL_GIT_HASH "unknown"
#endif

int handle_ping(const struct proto_ping_req *req, struct proto_ping_resp *resp, uint16_t *detail)
{
    (void)detail;
    memcpy(resp->data, req->data, req->data_len);
    resp->data_len = req->data_len;
    return 0;
}

/* Parse "major.minor.patch"; missing or non-numeric parts read 0, each saturates at 255. */
static void parse_version(const char *s, uint8_t v[3])
{
    for (int i = 0; i < 3; i++) {
        unsigned x = 0;
        while (*s >= '0' && *s <= '9') {
            x = x * 10u + (unsigned)(*s - '0');
            if (x > 255u) x = 255u;
            s++;
        }
        v[i] = (uint8_t)x;
        if (*s == '.') s++;
        else break;
    }
}

/* Copy at most cap - 1 characters and terminate (the response struct is zeroed). */
static void copy_str(char *dst, size_t cap, const char *src)
{
    size_t i = 0;
    for (; src != NULL && src[i] != '\0' && i + 1 < cap; i++) dst[i] = src[i];
    dst[i] = '\0';
}

/* DEV_ID (register file 0x00, 4 bytes): transaction header 0x00 = read, no sub-index, id 0. */
static uint32_t read_dev_id(void)
{
    const struct dw_ops *ops = board_dw_ops();
    if (ops == NULL || ops->spi_transfer == NULL) return 0;
    const uint8_t hdr[1] = {0x00};
    uint8_t rx[4] = {0};
    if (ops->spi_transfer(ops->ctx, hdr, 1, NULL, rx, 4) != 0) return 0;
    return (uint32_t)rx[0] | ((uint32_t)rx[1] << 8) | ((uint32_t)rx[2] << 16) | ((uint32_t)rx[3] << 24);
}

int handle_get_info(const struct proto_get_info_req *req, struct proto_get_info_resp *resp, uint16_t *detail)
{
    (void)req;
    (void)detail;
    uint8_t v[3] = {0, 0, 0};
    parse_version(UWBCAL_FW_VERSION, v);
    resp->protocol_version = PROTO_VERSION;
    resp->fw_major = v[0];
    resp->fw_minor = v[1];
    resp->fw_patch = v[2];
    copy_str(resp->git_hash, sizeof resp->git_hash, UWBCAL_GIT_HASH);
    copy_str(resp->board, sizeof resp->board, board_name());
    resp->dev_id = read_dev_id();
    board_uid(resp->uid);
    resp->max_payload = PROTO_MAX_PAYLOAD;
    return 0;
}

int handle_reset(const struct proto_reset_req *req, struct proto_reset_resp *resp, uint16_t *detail)
{
    (void)req;
    (void)resp;
    (void)detail;
    app_request_reset();
    return 0;
}
