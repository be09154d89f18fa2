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

/* ---------------------------------------------------------------------------------------------- message payloads */

static int printable_ascii(uint8_t c)
{
    return c >= 0x20u && c <= 0x7Eu;
}

/* A NUL-terminated text of at most size printable ASCII characters into size bytes, space padded; -1 if longer
 * (or not terminated) or not printable. */
static int pack_ascii(const char *text, uint8_t *out, size_t size)
{
    size_t i = 0;
    for (; i < size && text[i] != '\0'; i++) {
        uint8_t ch = (uint8_t)text[i];
        if (!printable_ascii(ch)) {
            return -1;
        }
        out[i] = ch;
    }
    if (i == size && text[i] != '\0') {
        return -1;
    }
    for (; i < size; i++) {
        out[i] = (uint8_t)' ';
    }
    return 0;
}

/* size bytes of printable ASCII into a NUL-terminated text without the trailing spaces (text holds size + 1
 * bytes); -1 if a byte is not printable. */
static int unpack_ascii(const uint8_t *in, size_t size, char *text)
{
    size_t end = 0;
    for (size_t i = 0; i < size; i++) {
        uint8_t ch = in[i];
        if (!printable_ascii(ch)) {
            return -1;
        }
        text[i] = (char)ch;
        if (ch != (uint8_t)' ') {
            end = i + 1u;
        }
    }
    text[end] = '\0';
    return 0;
}

/* BEGIN GENERATED messages by firmware/protocol/generate.py from messages.json: do not edit (make protocol) */
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
    return len >= BPROTO_LEN_SET_BRACKETS_MIN &&
           len == BPROTO_LEN_SET_BRACKETS_MIN + BPROTO_LEN_SET_BRACKETS_ITEM * (size_t)payload[4];
}

int bproto_pack_hello(const bproto_hello_t *m, uint8_t *out, size_t out_cap)
{
    if (out_cap < BPROTO_LEN_HELLO) {
        return -1;
    }
    out[0] = m->device_kind;
    out[1] = m->proto_minor;
    out[2] = m->fw_major;
    out[3] = m->fw_minor;
    out[4] = m->fw_patch;
    memcpy(&out[5], m->uid, BPROTO_UID_LEN);
    bproto_put_u32(&out[17], m->capabilities);
    return (int)BPROTO_LEN_HELLO;
}

int bproto_pack_ack(const bproto_ack_t *m, uint8_t *out, size_t out_cap)
{
    if (out_cap < BPROTO_LEN_ACK) {
        return -1;
    }
    bproto_put_u16(&out[0], m->acked_seq);
    return (int)BPROTO_LEN_ACK;
}

int bproto_pack_nack(const bproto_nack_t *m, uint8_t *out, size_t out_cap)
{
    if (out_cap < BPROTO_LEN_NACK) {
        return -1;
    }
    bproto_put_u16(&out[0], m->acked_seq);
    out[2] = m->code;
    return (int)BPROTO_LEN_NACK;
}

int bproto_pack_heartbeat(const bproto_heartbeat_t *m, uint8_t *out, size_t out_cap)
{
    if (out_cap < BPROTO_LEN_HEARTBEAT) {
        return -1;
    }
    bproto_put_u32(&out[0], m->uptime_ms);
    out[4] = m->state;
    return (int)BPROTO_LEN_HEARTBEAT;
}

int bproto_pack_ping(const bproto_ping_t *m, uint8_t *out, size_t out_cap)
{
    if (out_cap < BPROTO_LEN_PING) {
        return -1;
    }
    bproto_put_u64(&out[0], m->host_time_ns);
    return (int)BPROTO_LEN_PING;
}

int bproto_pack_pong(const bproto_pong_t *m, uint8_t *out, size_t out_cap)
{
    if (out_cap < BPROTO_LEN_PONG) {
        return -1;
    }
    bproto_put_u64(&out[0], m->host_time_ns);
    bproto_put_u64(&out[8], m->device_time_us);
    return (int)BPROTO_LEN_PONG;
}

int bproto_pack_set_brackets(const bproto_set_brackets_t *m, uint8_t *out, size_t out_cap)
{
    if (m->n > BPROTO_SET_BRACKETS_MAX_N) {
        return -1;
    }
    size_t len = BPROTO_LEN_SET_BRACKETS_MIN + BPROTO_LEN_SET_BRACKETS_ITEM * (size_t)m->n;
    if (out_cap < len) {
        return -1;
    }
    bproto_put_u32(&out[0], m->period_us);
    out[4] = m->n;
    for (size_t i = 0; i < m->n; i++) {
        bproto_put_u32(&out[BPROTO_LEN_SET_BRACKETS_MIN + BPROTO_LEN_SET_BRACKETS_ITEM * i], m->exposures_us[i]);
    }
    return (int)len;
}

int bproto_pack_start(const bproto_start_t *m, uint8_t *out, size_t out_cap)
{
    if (out_cap < BPROTO_LEN_START) {
        return -1;
    }
    bproto_put_u32(&out[0], m->session_id);
    return (int)BPROTO_LEN_START;
}

int bproto_pack_trigger(const bproto_trigger_t *m, uint8_t *out, size_t out_cap)
{
    if (out_cap < BPROTO_LEN_TRIGGER) {
        return -1;
    }
    bproto_put_u32(&out[0], m->session_id);
    bproto_put_u32(&out[4], m->trigger_seq);
    out[8] = m->bracket_index;
    bproto_put_u32(&out[9], m->exposure_us);
    bproto_put_u64(&out[13], m->t_start_us);
    return (int)BPROTO_LEN_TRIGGER;
}

int bproto_pack_panel_state(const bproto_panel_state_t *m, uint8_t *out, size_t out_cap)
{
    if (out_cap < BPROTO_LEN_PANEL_STATE) {
        return -1;
    }
    out[0] = m->cam_left;
    out[1] = m->cam_right;
    out[2] = m->trigger;
    out[3] = m->imu;
    out[4] = m->lidar;
    out[5] = m->gnss;
    bproto_put_u32(&out[6], m->free_disk_mb);
    bproto_put_u16(&out[10], m->fps_left_centi);
    bproto_put_u16(&out[12], m->fps_right_centi);
    bproto_put_u32(&out[14], m->rec_seconds);
    if (pack_ascii(m->message, &out[18], BPROTO_PANEL_MESSAGE_LEN) != 0) {
        return -1;
    }
    return (int)BPROTO_LEN_PANEL_STATE;
}

int bproto_pack_button(const bproto_button_t *m, uint8_t *out, size_t out_cap)
{
    if (out_cap < BPROTO_LEN_BUTTON) {
        return -1;
    }
    out[0] = m->button;
    out[1] = m->action;
    bproto_put_u16(&out[2], m->event_seq);
    return (int)BPROTO_LEN_BUTTON;
}

uint8_t bproto_unpack_hello(const uint8_t *payload, size_t len, bproto_hello_t *m)
{
    if (len != BPROTO_LEN_HELLO) {
        return BPROTO_NACK_BAD_LENGTH;
    }
    m->device_kind = payload[0];
    m->proto_minor = payload[1];
    m->fw_major = payload[2];
    m->fw_minor = payload[3];
    m->fw_patch = payload[4];
    memcpy(m->uid, &payload[5], BPROTO_UID_LEN);
    m->capabilities = bproto_get_u32(&payload[17]);
    return 0;
}

uint8_t bproto_unpack_ack(const uint8_t *payload, size_t len, bproto_ack_t *m)
{
    if (len != BPROTO_LEN_ACK) {
        return BPROTO_NACK_BAD_LENGTH;
    }
    m->acked_seq = bproto_get_u16(&payload[0]);
    return 0;
}

uint8_t bproto_unpack_nack(const uint8_t *payload, size_t len, bproto_nack_t *m)
{
    if (len != BPROTO_LEN_NACK) {
        return BPROTO_NACK_BAD_LENGTH;
    }
    m->acked_seq = bproto_get_u16(&payload[0]);
    m->code = payload[2];
    return 0;
}

uint8_t bproto_unpack_heartbeat(const uint8_t *payload, size_t len, bproto_heartbeat_t *m)
{
    if (len != BPROTO_LEN_HEARTBEAT) {
        return BPROTO_NACK_BAD_LENGTH;
    }
    m->uptime_ms = bproto_get_u32(&payload[0]);
    m->state = payload[4];
    return 0;
}

uint8_t bproto_unpack_ping(const uint8_t *payload, size_t len, bproto_ping_t *m)
{
    if (len != BPROTO_LEN_PING) {
        return BPROTO_NACK_BAD_LENGTH;
    }
    m->host_time_ns = bproto_get_u64(&payload[0]);
    return 0;
}

uint8_t bproto_unpack_pong(const uint8_t *payload, size_t len, bproto_pong_t *m)
{
    if (len != BPROTO_LEN_PONG) {
        return BPROTO_NACK_BAD_LENGTH;
    }
    m->host_time_ns = bproto_get_u64(&payload[0]);
    m->device_time_us = bproto_get_u64(&payload[8]);
    return 0;
}

uint8_t bproto_unpack_set_brackets(const uint8_t *payload, size_t len, bproto_set_brackets_t *m)
{
    if (!bproto_set_brackets_len_ok(payload, len)) {
        return BPROTO_NACK_BAD_LENGTH;
    }
    m->period_us = bproto_get_u32(&payload[0]);
    m->n = payload[4];
    for (size_t i = 0; i < m->n; i++) {
        m->exposures_us[i] = bproto_get_u32(&payload[BPROTO_LEN_SET_BRACKETS_MIN + BPROTO_LEN_SET_BRACKETS_ITEM * i]);
    }
    return 0;
}

uint8_t bproto_unpack_start(const uint8_t *payload, size_t len, bproto_start_t *m)
{
    if (len != BPROTO_LEN_START) {
        return BPROTO_NACK_BAD_LENGTH;
    }
    m->session_id = bproto_get_u32(&payload[0]);
    return 0;
}

uint8_t bproto_unpack_stop(const uint8_t *payload, size_t len)
{
    (void)payload;
    return len == BPROTO_LEN_STOP ? 0u : BPROTO_NACK_BAD_LENGTH;
}

uint8_t bproto_unpack_trigger(const uint8_t *payload, size_t len, bproto_trigger_t *m)
{
    if (len != BPROTO_LEN_TRIGGER) {
        return BPROTO_NACK_BAD_LENGTH;
    }
    m->session_id = bproto_get_u32(&payload[0]);
    m->trigger_seq = bproto_get_u32(&payload[4]);
    m->bracket_index = payload[8];
    m->exposure_us = bproto_get_u32(&payload[9]);
    m->t_start_us = bproto_get_u64(&payload[13]);
    return 0;
}

uint8_t bproto_unpack_panel_state(const uint8_t *payload, size_t len, bproto_panel_state_t *m)
{
    if (len != BPROTO_LEN_PANEL_STATE) {
        return BPROTO_NACK_BAD_LENGTH;
    }
    m->cam_left = payload[0];
    m->cam_right = payload[1];
    m->trigger = payload[2];
    m->imu = payload[3];
    m->lidar = payload[4];
    m->gnss = payload[5];
    m->free_disk_mb = bproto_get_u32(&payload[6]);
    m->fps_left_centi = bproto_get_u16(&payload[10]);
    m->fps_right_centi = bproto_get_u16(&payload[12]);
    m->rec_seconds = bproto_get_u32(&payload[14]);
    if (unpack_ascii(&payload[18], BPROTO_PANEL_MESSAGE_LEN, m->message) != 0) {
        return BPROTO_NACK_BAD_VALUE;
    }
    return 0;
}

uint8_t bproto_unpack_button(const uint8_t *payload, size_t len, bproto_button_t *m)
{
    if (len != BPROTO_LEN_BUTTON) {
        return BPROTO_NACK_BAD_LENGTH;
    }
    m->button = payload[0];
    m->action = payload[1];
    m->event_seq = bproto_get_u16(&payload[2]);
    return 0;
}

uint8_t bproto_check_panel_state(const bproto_panel_state_t *m)
{
    if (m->cam_left > BPROTO_PANEL_STATE_CAM_LEFT_MAX) {
        return BPROTO_NACK_BAD_VALUE;
    }
    if (m->cam_right > BPROTO_PANEL_STATE_CAM_RIGHT_MAX) {
        return BPROTO_NACK_BAD_VALUE;
    }
    if (m->trigger > BPROTO_PANEL_STATE_TRIGGER_MAX) {
        return BPROTO_NACK_BAD_VALUE;
    }
    if (m->imu > BPROTO_PANEL_STATE_IMU_MAX) {
        return BPROTO_NACK_BAD_VALUE;
    }
    if (m->lidar > BPROTO_PANEL_STATE_LIDAR_MAX) {
        return BPROTO_NACK_BAD_VALUE;
    }
    if (m->gnss > BPROTO_PANEL_STATE_GNSS_MAX) {
        return BPROTO_NACK_BAD_VALUE;
    }
    return 0;
}

int bproto_pack_msg(const bproto_msg_t *m, uint8_t *out, size_t out_cap)
{
    switch (m->type) {
    case BPROTO_MSG_HELLO: return m->hello_request ? 0 : bproto_pack_hello(&m->u.hello, out, out_cap);
    case BPROTO_MSG_ACK: return bproto_pack_ack(&m->u.ack, out, out_cap);
    case BPROTO_MSG_NACK: return bproto_pack_nack(&m->u.nack, out, out_cap);
    case BPROTO_MSG_HEARTBEAT: return bproto_pack_heartbeat(&m->u.heartbeat, out, out_cap);
    case BPROTO_MSG_PING: return bproto_pack_ping(&m->u.ping, out, out_cap);
    case BPROTO_MSG_PONG: return bproto_pack_pong(&m->u.pong, out, out_cap);
    case BPROTO_MSG_SET_BRACKETS: return bproto_pack_set_brackets(&m->u.set_brackets, out, out_cap);
    case BPROTO_MSG_START: return bproto_pack_start(&m->u.start, out, out_cap);
    case BPROTO_MSG_STOP: return 0;
    case BPROTO_MSG_TRIGGER: return bproto_pack_trigger(&m->u.trigger, out, out_cap);
    case BPROTO_MSG_PANEL_STATE: return bproto_pack_panel_state(&m->u.panel_state, out, out_cap);
    case BPROTO_MSG_BUTTON: return bproto_pack_button(&m->u.button, out, out_cap);
    default: return -1;
    }
}

uint8_t bproto_unpack_msg(uint8_t type, const uint8_t *payload, size_t len, bproto_msg_t *m)
{
    m->type = type;
    m->hello_request = 0;
    switch (type) {
    case BPROTO_MSG_HELLO:
        if (len == 0u) {
            m->hello_request = 1;
            return 0;
        }
        return bproto_unpack_hello(payload, len, &m->u.hello);
    case BPROTO_MSG_ACK: return bproto_unpack_ack(payload, len, &m->u.ack);
    case BPROTO_MSG_NACK: return bproto_unpack_nack(payload, len, &m->u.nack);
    case BPROTO_MSG_HEARTBEAT: return bproto_unpack_heartbeat(payload, len, &m->u.heartbeat);
    case BPROTO_MSG_PING: return bproto_unpack_ping(payload, len, &m->u.ping);
    case BPROTO_MSG_PONG: return bproto_unpack_pong(payload, len, &m->u.pong);
    case BPROTO_MSG_SET_BRACKETS: return bproto_unpack_set_brackets(payload, len, &m->u.set_brackets);
    case BPROTO_MSG_START: return bproto_unpack_start(payload, len, &m->u.start);
    case BPROTO_MSG_STOP: return bproto_unpack_stop(payload, len);
    case BPROTO_MSG_TRIGGER: return bproto_unpack_trigger(payload, len, &m->u.trigger);
    case BPROTO_MSG_PANEL_STATE: return bproto_unpack_panel_state(payload, len, &m->u.panel_state);
    case BPROTO_MSG_BUTTON: return bproto_unpack_button(payload, len, &m->u.button);
    default: return BPROTO_NACK_UNKNOWN_TYPE;
    }
}
/* END GENERATED messages */
