/*
 * bproto v1: the bracketry serial wire codec in C (frames, CRC-16/CCITT-FALSE, COBS, streaming decoder).
 *
 * The single specification is firmware/protocol/PROTOCOL.md; firmware/protocol/protocol_vectors.json holds the
 * shared test vectors (tests/wire runs them against this file compiled for the host).
 * C99, no malloc, fixed buffers, no dependencies beyond <stdint.h>/<stddef.h>/<string.h>.
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

#define BPROTO_VERSION 1
#define BPROTO_MAX_PAYLOAD 255u
#define BPROTO_HEADER_LEN 6u
#define BPROTO_CRC_LEN 2u
/* largest body: header + payload + crc */
#define BPROTO_MAX_BODY (BPROTO_HEADER_LEN + BPROTO_MAX_PAYLOAD + BPROTO_CRC_LEN)
/* largest COBS-encoded body without the delimiter: one overhead byte per started 254-byte block */
#define BPROTO_MAX_ENCODED (BPROTO_MAX_BODY + (BPROTO_MAX_BODY + 253u) / 254u)
/* worst-case encoded frame including the trailing 0x00 */
#define BPROTO_MAX_FRAME (BPROTO_MAX_ENCODED + 1u)

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

/* payload sizes of the fixed-layout messages (bytes) */
#define BPROTO_LEN_HELLO 21u /* device->host; the host's request is empty */
#define BPROTO_LEN_ACK 2u
#define BPROTO_LEN_NACK 3u
#define BPROTO_LEN_HEARTBEAT 5u
#define BPROTO_LEN_PING 8u
#define BPROTO_LEN_PONG 16u
#define BPROTO_LEN_START 4u
#define BPROTO_LEN_STOP 0u
#define BPROTO_LEN_TRIGGER 21u
#define BPROTO_LEN_PANEL_STATE 38u
#define BPROTO_LEN_BUTTON 4u
/* SET_BRACKETS: 5 + 4 * n bytes */
#define BPROTO_MAX_BRACKETS 16u
#define BPROTO_MIN_PERIOD_US 1000u
#define BPROTO_MAX_PERIOD_US 1000000u
#define BPROTO_MIN_EXPOSURE_US 10u
#define BPROTO_EXPOSURE_MARGIN_US 200u

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
/* 1 if a SET_BRACKETS payload of len bytes is structurally valid (5 + 4 * n). */
int bproto_set_brackets_len_ok(const uint8_t *payload, size_t len);
/* 0 if SET_BRACKETS values are acceptable, else BPROTO_NACK_BAD_VALUE (see PROTOCOL.md). */
uint8_t bproto_check_set_brackets(uint32_t period_us, const uint32_t *exposures_us, size_t n);

#ifdef __cplusplus
}
#endif

#endif /* BPROTO_H */
