/*
 * bproto v1: the bracketry serial wire codec in C (frames, CRC-16/CCITT-FALSE, COBS, streaming decoder, and a
 * struct with pack/unpack functions for every message payload).
 *
 * The single specification is firmware/protocol/PROTOCOL.md; firmware/protocol/protocol_vectors.json holds the
 * shared test vectors (tests/firmware/protocol runs them against this file compiled for the host).
 * C99, no malloc, fixed buffers, no dependencies beyond <stdint.h>/<stddef.h>/<string.h>.
 * The parts between BEGIN/END GENERATED markers (here and in bproto.c) are written by firmware/protocol/generate.py
 * from firmware/protocol/messages.json (make protocol); edit the table, not them.
 *
 * Frame on the wire: COBS(body) 0x00,
 *   body = ver:u8 | type:u8 | seq:u16 | len:u16 | payload[len] | crc:u16   (little-endian)
 *   crc  = CRC-16/CCITT-FALSE over ver..payload.
 */
#ifndef BPROTO_H
#define BPROTO_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* BEGIN GENERATED constants by firmware/protocol/generate.py from messages.json: do not edit (make protocol) */
#define BPROTO_VERSION 1

#define BPROTO_MSG_HELLO 0x01u
#define BPROTO_MSG_ACK 0x02u
#define BPROTO_MSG_NACK 0x03u
#define BPROTO_MSG_HEARTBEAT 0x04u
#define BPROTO_MSG_PING 0x05u
#define BPROTO_MSG_PONG 0x06u
#define BPROTO_MSG_SET_BRACKETS 0x10u
#define BPROTO_MSG_START 0x11u
#define BPROTO_MSG_STOP 0x12u
#define BPROTO_MSG_TRIGGER 0x20u
#define BPROTO_MSG_PANEL_STATE 0x30u
#define BPROTO_MSG_BUTTON 0x31u

#define BPROTO_NACK_UNKNOWN_TYPE 1u
#define BPROTO_NACK_BAD_LENGTH 2u
#define BPROTO_NACK_BAD_VALUE 3u
#define BPROTO_NACK_BAD_STATE 4u

#define BPROTO_DEVICE_TRIGGER 1u
#define BPROTO_DEVICE_PANEL 2u

/* payload sizes (bytes); a variable message: its fixed part (_MIN) and one array item (_ITEM) */
#define BPROTO_LEN_HELLO 21u /* device->host; the host's request is empty */
#define BPROTO_LEN_ACK 2u
#define BPROTO_LEN_NACK 3u
#define BPROTO_LEN_HEARTBEAT 5u
#define BPROTO_LEN_PING 8u
#define BPROTO_LEN_PONG 16u
#define BPROTO_LEN_SET_BRACKETS_MIN 5u
#define BPROTO_LEN_SET_BRACKETS_ITEM 4u
#define BPROTO_LEN_START 4u
#define BPROTO_LEN_STOP 0u
#define BPROTO_LEN_TRIGGER 21u
#define BPROTO_LEN_PANEL_STATE 38u
#define BPROTO_LEN_BUTTON 4u

/* sizes of the fixed-size text and byte fields */
#define BPROTO_UID_LEN 12u
#define BPROTO_PANEL_MESSAGE_LEN 20u

/* SET_BRACKETS value rule (see bproto_check_set_brackets) */
#define BPROTO_MAX_BRACKETS 16u
#define BPROTO_MIN_PERIOD_US 1000u
#define BPROTO_MAX_PERIOD_US 1000000u
#define BPROTO_MIN_EXPOSURE_US 10u
#define BPROTO_EXPOSURE_MARGIN_US 200u
#define BPROTO_PANEL_STATE_CAM_LEFT_MAX 4u
#define BPROTO_PANEL_STATE_CAM_RIGHT_MAX 4u
#define BPROTO_PANEL_STATE_TRIGGER_MAX 4u
#define BPROTO_PANEL_STATE_IMU_MAX 4u
#define BPROTO_PANEL_STATE_LIDAR_MAX 4u
#define BPROTO_PANEL_STATE_GNSS_MAX 4u
/* END GENERATED constants */

#define BPROTO_MAX_PAYLOAD 255u
#define BPROTO_HEADER_LEN 6u
#define BPROTO_CRC_LEN 2u
/* largest body: header + payload + crc */
#define BPROTO_MAX_BODY (BPROTO_HEADER_LEN + BPROTO_MAX_PAYLOAD + BPROTO_CRC_LEN)
/* largest COBS-encoded body without the delimiter: one overhead byte per started 254-byte block */
#define BPROTO_MAX_ENCODED (BPROTO_MAX_BODY + (BPROTO_MAX_BODY + 253u) / 254u)
/* worst-case encoded frame including the trailing 0x00 */
#define BPROTO_MAX_FRAME (BPROTO_MAX_ENCODED + 1u)

typedef struct {
    uint8_t ver, type;
    uint16_t seq, len;
    uint8_t payload[BPROTO_MAX_PAYLOAD];
} bproto_frame_t;

typedef struct {
    /* private: encoded bytes since the last 0x00 (decoded in place at the delimiter) */
    uint8_t buf[BPROTO_MAX_ENCODED];
    uint16_t n;
    uint8_t overflow;
    /* public counters (same meaning as the Python Decoder.stats) */
    uint32_t frames_ok, crc_errors, length_errors, cobs_errors, overflows;
    uint32_t version_errors, bytes_discarded;
} bproto_decoder_t;

/* CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0); "123456789" -> 0x29B1 */
uint16_t bproto_crc16(const uint8_t *data, size_t len);

/* COBS-encode len bytes into out (no delimiter); returns bytes written, or 0 if out_cap is too small. */
size_t bproto_cobs_encode(const uint8_t *in, size_t len, uint8_t *out, size_t out_cap);
/* COBS-decode len bytes (no 0x00 allowed) into out (out may equal in); returns bytes written, or -1 on bad input
 * or if out_cap is too small. */
long bproto_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t out_cap);

/* One frame into out: returns bytes written including the trailing 0x00, or 0 on error (len > 255, out too small,
 * payload NULL with len > 0). out_cap >= BPROTO_MAX_FRAME always suffices. */
size_t bproto_encode_frame(uint8_t type, uint16_t seq, const uint8_t *payload, size_t len, uint8_t *out,
                           size_t out_cap);

void bproto_decoder_init(bproto_decoder_t *d);
/* Drop any partial frame (counters kept). */
void bproto_decoder_reset(bproto_decoder_t *d);
/* Feed one byte; returns 1 when *out holds a new valid frame (CRC, length and version checked), else 0. */
int bproto_decoder_feed(bproto_decoder_t *d, uint8_t byte, bproto_frame_t *out);

/* little-endian helpers */
void bproto_put_u16(uint8_t *p, uint16_t v);
void bproto_put_u32(uint8_t *p, uint32_t v);
void bproto_put_u64(uint8_t *p, uint64_t v);
uint16_t bproto_get_u16(const uint8_t *p);
uint32_t bproto_get_u32(const uint8_t *p);
uint64_t bproto_get_u64(const uint8_t *p);

/* Expected payload length of a fixed-layout type for a device receiving it (HELLO: 0), -1 for SET_BRACKETS (use
 * bproto_set_brackets_len_ok), -2 for an unknown type. */
int bproto_expected_len(uint8_t type);
/* 0 if SET_BRACKETS values are acceptable, else BPROTO_NACK_BAD_VALUE (see PROTOCOL.md). */
uint8_t bproto_check_set_brackets(uint32_t period_us, const uint32_t *exposures_us, size_t n);

/* ---------------------------------------------------------------------------------------------- message payloads
 * One struct per message type with its fields as in PROTOCOL.md section 3 (names as in the Python codec), a pack
 * function (struct -> payload bytes, explicit little-endian) and an unpack function (payload bytes -> struct).
 *
 * pack:   returns the payload length written to out (0..255), or -1 if out_cap is too small or a field cannot be
 *         packed (SET_BRACKETS n > BPROTO_SET_BRACKETS_MAX_N; PANEL_STATE message longer than 20 characters or not
 *         printable ASCII) - the cases where the Python pack_payload raises ValueError.
 * unpack: returns 0 and fills *m, or the NACK code a device answers (*m then unspecified), exactly like the Python
 *         unpack_payload / nack_code_for: BPROTO_NACK_BAD_LENGTH for a length that does not match the layout,
 *         BPROTO_NACK_BAD_VALUE for a PANEL_STATE message that is not printable ASCII (0x20..0x7E). Value ranges of
 *         the semantics (SET_BRACKETS bounds, PANEL_STATE states <= 4, ...) are not checked here: see
 *         bproto_check_set_brackets().
 */
/* BEGIN GENERATED messages by firmware/protocol/generate.py from messages.json: do not edit (make protocol) */
/* most exposures_us a SET_BRACKETS payload can carry (the structural limit) */
#define BPROTO_SET_BRACKETS_MAX_N ((BPROTO_MAX_PAYLOAD - BPROTO_LEN_SET_BRACKETS_MIN) / BPROTO_LEN_SET_BRACKETS_ITEM)

typedef struct { /* 0x01 HELLO, device→host */
    uint8_t device_kind;  /* 1 trigger, 2 panel */
    uint8_t proto_minor;
    uint8_t fw_major;
    uint8_t fw_minor;
    uint8_t fw_patch;
    uint8_t uid[BPROTO_UID_LEN];  /* STM32 96-bit UID, or ESP32 MAC zero-padded */
    uint32_t capabilities;  /* bitfield, device-specific */
} bproto_hello_t;

typedef struct { /* 0x02 ACK, both */
    uint16_t acked_seq;
} bproto_ack_t;

typedef struct { /* 0x03 NACK, both */
    uint16_t acked_seq;
    uint8_t code;  /* NACK code */
} bproto_nack_t;

typedef struct { /* 0x04 HEARTBEAT, both */
    uint32_t uptime_ms;  /* wraps */
    uint8_t state;  /* trigger: 0 idle, 1 running; panel: 0 normal, 1 host lost; host: 0 */
} bproto_heartbeat_t;

typedef struct { /* 0x05 PING, host→device */
    uint64_t host_time_ns;
} bproto_ping_t;

typedef struct { /* 0x06 PONG, device→host */
    uint64_t host_time_ns;  /* echoed */
    uint64_t device_time_us;  /* 64-bit device microsecond clock */
} bproto_pong_t;

typedef struct { /* 0x10 SET_BRACKETS, host→trigger */
    uint32_t period_us;
    uint8_t n;
    uint32_t exposures_us[BPROTO_SET_BRACKETS_MAX_N];  /* n = 1..16 */
} bproto_set_brackets_t;

typedef struct { /* 0x11 START, host→trigger */
    uint32_t session_id;
} bproto_start_t;

/* 0x12 STOP has no fields (empty payload). */

typedef struct { /* 0x20 TRIGGER, trigger→host */
    uint32_t session_id;
    uint32_t trigger_seq;
    uint8_t bracket_index;
    uint32_t exposure_us;
    uint64_t t_start_us;
} bproto_trigger_t;

typedef struct { /* 0x30 PANEL_STATE, host→panel */
    uint8_t cam_left;  /* 0 OFF, 1 IDLE, 2 REC, 3 ERR, 4 CAL */
    uint8_t cam_right;
    uint8_t trigger;
    uint8_t imu;
    uint8_t lidar;
    uint8_t gnss;
    uint32_t free_disk_mb;
    uint16_t fps_left_centi;  /* fps × 100 */
    uint16_t fps_right_centi;
    uint32_t rec_seconds;
    char message[BPROTO_PANEL_MESSAGE_LEN + 1u];  /* NUL-terminated printable ASCII: space padded when packed, trailing spaces removed when unpacked */
} bproto_panel_state_t;

typedef struct { /* 0x31 BUTTON, panel→host */
    uint8_t button;  /* 1 SENSORS, 2 RECORD */
    uint8_t action;  /* 1 short, 2 long */
    uint16_t event_seq;
} bproto_button_t;

int bproto_pack_hello(const bproto_hello_t *m, uint8_t *out, size_t out_cap);
int bproto_pack_ack(const bproto_ack_t *m, uint8_t *out, size_t out_cap);
int bproto_pack_nack(const bproto_nack_t *m, uint8_t *out, size_t out_cap);
int bproto_pack_heartbeat(const bproto_heartbeat_t *m, uint8_t *out, size_t out_cap);
int bproto_pack_ping(const bproto_ping_t *m, uint8_t *out, size_t out_cap);
int bproto_pack_pong(const bproto_pong_t *m, uint8_t *out, size_t out_cap);
int bproto_pack_set_brackets(const bproto_set_brackets_t *m, uint8_t *out, size_t out_cap);
int bproto_pack_start(const bproto_start_t *m, uint8_t *out, size_t out_cap);
int bproto_pack_trigger(const bproto_trigger_t *m, uint8_t *out, size_t out_cap);
int bproto_pack_panel_state(const bproto_panel_state_t *m, uint8_t *out, size_t out_cap);
int bproto_pack_button(const bproto_button_t *m, uint8_t *out, size_t out_cap);
uint8_t bproto_unpack_hello(const uint8_t *payload, size_t len, bproto_hello_t *m);
uint8_t bproto_unpack_ack(const uint8_t *payload, size_t len, bproto_ack_t *m);
uint8_t bproto_unpack_nack(const uint8_t *payload, size_t len, bproto_nack_t *m);
uint8_t bproto_unpack_heartbeat(const uint8_t *payload, size_t len, bproto_heartbeat_t *m);
uint8_t bproto_unpack_ping(const uint8_t *payload, size_t len, bproto_ping_t *m);
uint8_t bproto_unpack_pong(const uint8_t *payload, size_t len, bproto_pong_t *m);
uint8_t bproto_unpack_set_brackets(const uint8_t *payload, size_t len, bproto_set_brackets_t *m);
uint8_t bproto_unpack_start(const uint8_t *payload, size_t len, bproto_start_t *m);
uint8_t bproto_unpack_stop(const uint8_t *payload, size_t len);
uint8_t bproto_unpack_trigger(const uint8_t *payload, size_t len, bproto_trigger_t *m);
uint8_t bproto_unpack_panel_state(const uint8_t *payload, size_t len, bproto_panel_state_t *m);
uint8_t bproto_unpack_button(const uint8_t *payload, size_t len, bproto_button_t *m);
/* 1 if a SET_BRACKETS payload of len bytes is structurally valid */
int bproto_set_brackets_len_ok(const uint8_t *payload, size_t len);
/* 0 if the PANEL_STATE values are within their ranges, else BPROTO_NACK_BAD_VALUE */
uint8_t bproto_check_panel_state(const bproto_panel_state_t *m);

/* Any message: type plus the struct of that type. */
typedef struct {
    uint8_t type;          /* BPROTO_MSG_* */
    uint8_t hello_request; /* HELLO only: 1 = the host's request (empty payload, u.hello unused) */
    union {
        bproto_hello_t hello;
        bproto_ack_t ack;
        bproto_nack_t nack;
        bproto_heartbeat_t heartbeat;
        bproto_ping_t ping;
        bproto_pong_t pong;
        bproto_set_brackets_t set_brackets;
        bproto_start_t start;
        bproto_trigger_t trigger;
        bproto_panel_state_t panel_state;
        bproto_button_t button;
    } u;
} bproto_msg_t;
/* END GENERATED messages */

/* Payload of m (dispatch on m->type); -1 on an unknown type or as the per-type pack functions. */
int bproto_pack_msg(const bproto_msg_t *m, uint8_t *out, size_t out_cap);
/* Unpack a payload of any type into *m (m->type = type); returns 0, BPROTO_NACK_UNKNOWN_TYPE, BPROTO_NACK_BAD_LENGTH
 * or BPROTO_NACK_BAD_VALUE: the same result as the Python nack_code_for(type, payload). HELLO: an empty payload is
 * the request (hello_request = 1), 21 bytes a device HELLO, anything else BAD_LENGTH. */
uint8_t bproto_unpack_msg(uint8_t type, const uint8_t *payload, size_t len, bproto_msg_t *m);

#ifdef __cplusplus
}
#endif

#endif /* BPROTO_H */
