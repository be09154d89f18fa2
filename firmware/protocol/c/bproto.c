/* bproto v1 C codec; see bproto.h and firmware/protocol/PROTOCOL.md. */
#include "bproto.h"

#include <string.h>

uint16_t bproto_crc16(const uint8_t *data, size_t len)
{
    uint32_t crc = 0xFFFFu;
    for (size_t i = 0; i < len; i++) {
        crc ^= (uint32_t)data[i] << 8;
        for (int b = 0; b < 8; b++) {
            crc = (crc & 0x8000u) ? ((crc << 1) ^ 0x1021u) : (crc << 1);
        }
        crc &= 0xFFFFu;
    }
    return (uint16_t)crc;
}

size_t bproto_cobs_encode(const uint8_t *in, size_t len, uint8_t *out, size_t out_cap)
{
    size_t w = 1;          /* write position */
    size_t code_pos = 0;   /* where the current block's code byte goes */
    uint8_t code = 1;
    if (out_cap < 1) {
        return 0;
    }
    for (size_t i = 0; i < len; i++) {
        if (in[i] == 0) {
            out[code_pos] = code;
            code_pos = w++;
            code = 1;
            if (w > out_cap) {
                return 0;
            }
        } else {
            if (w >= out_cap) {
                return 0;
            }
            out[w++] = in[i];
            code++;
            if (code == 0xFFu) {
                out[code_pos] = code;
                code = 1;
                if (i + 1 == len) {
                    return w; /* a final full block ends the encoding (no extra 0x01) */
                }
                code_pos = w++;
                if (w > out_cap) {
                    return 0;
                }
            }
        }
    }
    out[code_pos] = code;
    return w;
}

long bproto_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t out_cap)
{
    size_t r = 0;
    size_t w = 0;
    while (r < len) {
        uint8_t code = in[r];
        if (code == 0) {
            return -1;
        }
        size_t end = r + code;
        if (end > len) {
            return -1;
        }
        r++;
        while (r < end) {
            if (in[r] == 0 || w >= out_cap) {
                return -1;
            }
            out[w++] = in[r++];
        }
        if (code < 0xFFu && r < len) {
            if (w >= out_cap) {
                return -1;
            }
            out[w++] = 0;
        }
    }
    return (long)w;
}

size_t bproto_encode_frame(uint8_t type, uint16_t seq, const uint8_t *payload, size_t len, uint8_t *out,
                           size_t out_cap)
{
    uint8_t body[BPROTO_MAX_BODY];
    if (len > BPROTO_MAX_PAYLOAD || (len > 0 && payload == NULL) || out == NULL) {
        return 0;
    }
    body[0] = BPROTO_VERSION;
    body[1] = type;
    bproto_put_u16(&body[2], seq);
    bproto_put_u16(&body[4], (uint16_t)len);
    if (len > 0) {
        memcpy(&body[BPROTO_HEADER_LEN], payload, len);
    }
    size_t n = BPROTO_HEADER_LEN + len;
    bproto_put_u16(&body[n], bproto_crc16(body, n));
    n += BPROTO_CRC_LEN;
    if (out_cap < 2) {
        return 0;
    }
    size_t w = bproto_cobs_encode(body, n, out, out_cap - 1);
    if (w == 0) {
        return 0;
    }
    out[w] = 0;
    return w + 1;
}

void bproto_decoder_init(bproto_decoder_t *d)
{
    memset(d, 0, sizeof(*d));
}

void bproto_decoder_reset(bproto_decoder_t *d)
{
    d->n = 0;
    d->overflow = 0;
}

static void reject(bproto_decoder_t *d, uint32_t *counter, uint16_t encoded_len)
{
    (*counter)++;
    d->bytes_discarded += encoded_len;
}

static int end_of_frame(bproto_decoder_t *d, bproto_frame_t *out)
{
    uint16_t enc = d->n;
    d->n = 0;
    if (d->overflow) {
        d->overflow = 0;
        return 0;
    }
    if (enc == 0) {
        return 0; /* empty frame: ignored */
    }
    long blen = bproto_cobs_decode(d->buf, enc, d->buf, sizeof(d->buf));
    if (blen < 0) {
        reject(d, &d->cobs_errors, enc);
        return 0;
    }
    size_t n = (size_t)blen;
    if (n < BPROTO_HEADER_LEN + BPROTO_CRC_LEN) {
        reject(d, &d->length_errors, enc);
        return 0;
    }
    if (bproto_crc16(d->buf, n - 2) != bproto_get_u16(&d->buf[n - 2])) {
        reject(d, &d->crc_errors, enc);
        return 0;
    }
    uint16_t len = bproto_get_u16(&d->buf[4]);
    if (len > BPROTO_MAX_PAYLOAD || (size_t)len != n - BPROTO_HEADER_LEN - BPROTO_CRC_LEN) {
        reject(d, &d->length_errors, enc);
        return 0;
    }
    if (d->buf[0] != BPROTO_VERSION) {
        reject(d, &d->version_errors, enc);
        return 0;
    }
    out->ver = d->buf[0];
    out->type = d->buf[1];
    out->seq = bproto_get_u16(&d->buf[2]);
    out->len = len;
    memcpy(out->payload, &d->buf[BPROTO_HEADER_LEN], len);
    d->frames_ok++;
    return 1;
}

int bproto_decoder_feed(bproto_decoder_t *d, uint8_t byte, bproto_frame_t *out)
{
    if (byte == 0) {
        return end_of_frame(d, out);
    }
    if (d->overflow) {
        d->bytes_discarded++;
        return 0;
    }
    if (d->n >= BPROTO_MAX_ENCODED) {
        d->overflows++;
        d->bytes_discarded += (uint32_t)d->n + 1u;
        d->n = 0;
        d->overflow = 1;
        return 0;
    }
    d->buf[d->n++] = byte;
    return 0;
}

void bproto_put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
}

void bproto_put_u32(uint8_t *p, uint32_t v)
{
    for (int i = 0; i < 4; i++) {
        p[i] = (uint8_t)(v >> (8 * i));
    }
}

void bproto_put_u64(uint8_t *p, uint64_t v)
{
    for (int i = 0; i < 8; i++) {
        p[i] = (uint8_t)(v >> (8 * i));
    }
}

uint16_t bproto_get_u16(const uint8_t *p)
{
    return (uint16_t)((uint16_t)p[0] | (uint16_t)((uint16_t)p[1] << 8));
}

uint32_t bproto_get_u32(const uint8_t *p)
{
    uint32_t v = 0;
    for (int i = 3; i >= 0; i--) {
        v = (v << 8) | p[i];
    }
    return v;
}

uint64_t bproto_get_u64(const uint8_t *p)
{
    uint64_t v = 0;
    for (int i = 7; i >= 0; i--) {
        v = (v << 8) | p[i];
    }
    return v;
}

int bproto_expected_len(uint8_t type)
{
    switch (type) {
    case BPROTO_MSG_HELLO: return 0;
    case BPROTO_MSG_ACK: return (int)BPROTO_LEN_ACK;
    case BPROTO_MSG_NACK: return (int)BPROTO_LEN_NACK;
    case BPROTO_MSG_HEARTBEAT: return (int)BPROTO_LEN_HEARTBEAT;
    case BPROTO_MSG_PING: return (int)BPROTO_LEN_PING;
    case BPROTO_MSG_PONG: return (int)BPROTO_LEN_PONG;
    case BPROTO_MSG_SET_BRACKETS: return -1;
    case BPROTO_MSG_START: return (int)BPROTO_LEN_START;
    case BPROTO_MSG_STOP: return (int)BPROTO_LEN_STOP;
    case BPROTO_MSG_TRIGGER: return (int)BPROTO_LEN_TRIGGER;
    case BPROTO_MSG_PANEL_STATE: return (int)BPROTO_LEN_PANEL_STATE;
    case BPROTO_MSG_BUTTON: return (int)BPROTO_LEN_BUTTON;
    default: return -2;
    }
}

int bproto_set_brackets_len_ok(const uint8_t *payload, size_t len)
{
    return len >= 5u && len == 5u + 4u * (size_t)payload[4];
}

uint8_t bproto_check_set_brackets(uint32_t period_us, const uint32_t *exposures_us, size_t n)
{
    if (n < 1u || n > BPROTO_MAX_BRACKETS) {
        return BPROTO_NACK_BAD_VALUE;
    }
    if (period_us < BPROTO_MIN_PERIOD_US || period_us > BPROTO_MAX_PERIOD_US) {
        return BPROTO_NACK_BAD_VALUE;
    }
    for (size_t i = 0; i < n; i++) {
        if (exposures_us[i] < BPROTO_MIN_EXPOSURE_US || exposures_us[i] > period_us - BPROTO_EXPOSURE_MARGIN_US) {
            return BPROTO_NACK_BAD_VALUE;
        }
    }
    return 0;
}
