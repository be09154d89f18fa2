/*
 * test_core.c - host unit tests of the portable trigger core (trigger_core.c + the real C codec bproto.c) with a
 * scripted fake HAL: validation bounds, scheduler cycling, 32->64-bit time extension across overflow, every NACK
 * path, START/STOP semantics, event order and queue overflow. Exit status 0 = all passed.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bproto.h"
#include "hal.h"
#include "trigger_core.h"

static int failures;
#define CHECK(cond)                                                                                                    \
    do {                                                                                                               \
        if (!(cond)) {                                                                                                 \
            fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #cond);                                   \
            failures++;                                                                                                \
        }                                                                                                              \
    } while (0)

/* ---- fake HAL ---- */
static uint8_t tx[65536];
static size_t tx_len;
static size_t tx_cap = sizeof(tx);
static uint64_t now_us;
static int timer_running, start_calls, stop_calls;
static trig_table_t started;

uint64_t hal_time_us(void) { return now_us; }
uint32_t hal_millis(void) { return (uint32_t)(now_us / 1000u); }
size_t hal_uart_write(const uint8_t *data, size_t len)
{
    if (tx_len + len > tx_cap) {
        return 0u;
    }
    memcpy(tx + tx_len, data, len);
    tx_len += len;
    return len;
}
void hal_trigger_start(const trig_table_t *table) { started = *table; timer_running = 1; start_calls++; }
void hal_trigger_stop(void) { timer_running = 0; stop_calls++; }
void hal_uid(uint8_t out[12]) { for (int i = 0; i < 12; i++) out[i] = (uint8_t)(0xA0 + i); }
uint32_t hal_irq_save(void) { return 0u; }
void hal_irq_restore(uint32_t state) { (void)state; }
void hal_led(int on) { (void)on; }

/* ---- helpers ---- */
typedef struct { uint8_t type; uint16_t seq, len; uint8_t p[BPROTO_MAX_PAYLOAD]; } msg_t;
static msg_t msgs[4096];
static int n_msgs;

static void collect(void)
{
    bproto_decoder_t d;
    bproto_frame_t f;
    bproto_decoder_init(&d);
    n_msgs = 0;
    for (size_t i = 0; i < tx_len; i++) {
        if (bproto_decoder_feed(&d, tx[i], &f)) {
            msgs[n_msgs].type = f.type;
            msgs[n_msgs].seq = f.seq;
            msgs[n_msgs].len = f.len;
            memcpy(msgs[n_msgs].p, f.payload, f.len);
            n_msgs++;
        }
    }
    tx_len = 0;
}

static void send(trig_core_t *c, uint8_t type, uint16_t seq, const uint8_t *p, size_t len)
{
    uint8_t out[BPROTO_MAX_FRAME];
    size_t n = bproto_encode_frame(type, seq, p, len, out, sizeof(out));
    for (size_t i = 0; i < n; i++) {
        trig_core_rx_byte(c, out[i]);
    }
}

/* the single reply to a command: 0 = ACK, else NACK code */
static int reply_code(uint16_t seq)
{
    collect();
    int code = -1, count = 0;
    for (int i = 0; i < n_msgs; i++) {
        if (msgs[i].type == BPROTO_MSG_ACK && bproto_get_u16(msgs[i].p) == seq) {
            code = 0;
            count++;
        } else if (msgs[i].type == BPROTO_MSG_NACK && bproto_get_u16(msgs[i].p) == seq) {
            code = msgs[i].p[2];
            count++;
        }
    }
    return count == 1 ? code : -100 - count;
}

static size_t brackets(uint8_t *p, uint32_t period, uint8_t n, const uint32_t *e)
{
    bproto_put_u32(p, period);
    p[4] = n;
    for (uint8_t i = 0; i < n; i++) bproto_put_u32(p + 5 + 4 * i, e[i]);
    return 5u + 4u * n;
}

static void test_timeext(void)
{
    trig_timeext_t t;
    trig_timeext_init(&t, 0xFFFFFF00u);
    CHECK(trig_timeext_extend(&t, 0xFFFFFFF0u) == 0xFFFFFFF0u);
    CHECK(trig_timeext_extend(&t, 0x00000010u) == 0x100000010ull);
    CHECK(trig_timeext_extend(&t, 0x00000010u) == 0x100000010ull);
    CHECK(trig_timeext_extend(&t, 0x80000000u) == 0x180000000ull);
    CHECK(trig_timeext_extend(&t, 0x00000001u) == 0x200000001ull);
    uint64_t prev = 0;
    trig_timeext_init(&t, 0u);
    for (uint64_t v = 0; v < 5ull << 32; v += 0x3FFFFFFFull) { /* monotonic across 5 wraps */
        uint64_t e = trig_timeext_extend(&t, (uint32_t)v);
        CHECK(e == v && e >= prev);
        prev = e;
    }
}

static void test_validation(void)
{
    uint32_t ok[6] = {1000, 2000, 4000, 8000, 16000, 32000};
    CHECK(bproto_check_set_brackets(45454u, ok, 6) == 0u);
    CHECK(bproto_check_set_brackets(999u, (uint32_t[]){10}, 1) == BPROTO_NACK_BAD_VALUE);
    CHECK(bproto_check_set_brackets(1000u, (uint32_t[]){10}, 1) == 0u);
    CHECK(bproto_check_set_brackets(1000u, (uint32_t[]){800}, 1) == 0u);
    CHECK(bproto_check_set_brackets(1000u, (uint32_t[]){801}, 1) == BPROTO_NACK_BAD_VALUE);
    CHECK(bproto_check_set_brackets(1000000u, (uint32_t[]){999800}, 1) == 0u);
    CHECK(bproto_check_set_brackets(1000001u, (uint32_t[]){10}, 1) == BPROTO_NACK_BAD_VALUE);
    CHECK(bproto_check_set_brackets(45454u, (uint32_t[]){9}, 1) == BPROTO_NACK_BAD_VALUE);
    CHECK(bproto_check_set_brackets(45454u, (uint32_t[]){0xFFFFFFFFu}, 1) == BPROTO_NACK_BAD_VALUE);
    CHECK(bproto_check_set_brackets(45454u, ok, 0) == BPROTO_NACK_BAD_VALUE);
    uint32_t many[17];
    for (int i = 0; i < 17; i++) many[i] = 100;
    CHECK(bproto_check_set_brackets(45454u, many, 16) == 0u);
    CHECK(bproto_check_set_brackets(45454u, many, 17) == BPROTO_NACK_BAD_VALUE);
    for (uint32_t k = 0; k < 100; k++) CHECK(trig_sched_index(k, 6) == k % 6);
    CHECK(trig_sched_index(0xFFFFFFFFu, 6) == 0xFFFFFFFFu % 6);
}

static void test_protocol(void)
{
    static trig_core_t c;
    trig_core_init(&c, 0x14u);
    tx_len = 0;
    trig_core_boot(&c, 0);
    collect();
    CHECK(n_msgs == 1 && msgs[0].type == BPROTO_MSG_HELLO && msgs[0].len == 21 && msgs[0].p[0] == 1);
    CHECK(bproto_get_u32(&msgs[0].p[17]) == 0x14u && msgs[0].p[5] == 0xA0);

    send(&c, BPROTO_MSG_HELLO, 1, NULL, 0);
    collect();
    CHECK(n_msgs == 1 && msgs[0].type == BPROTO_MSG_HELLO);
    send(&c, BPROTO_MSG_HELLO, 2, (const uint8_t *)"x", 1);
    CHECK(reply_code(2) == BPROTO_NACK_BAD_LENGTH);

    uint8_t ping[8];
    bproto_put_u64(ping, 0x1122334455667788ull);
    now_us = 0x123456789ull;
    send(&c, BPROTO_MSG_PING, 3, ping, 8);
    collect();
    CHECK(n_msgs == 1 && msgs[0].type == BPROTO_MSG_PONG && bproto_get_u64(msgs[0].p) == 0x1122334455667788ull);
    CHECK(bproto_get_u64(msgs[0].p + 8) == 0x123456789ull);
    send(&c, BPROTO_MSG_PING, 4, ping, 7);
    CHECK(reply_code(4) == BPROTO_NACK_BAD_LENGTH);

    send(&c, 0x7E, 5, NULL, 0);
    CHECK(reply_code(5) == BPROTO_NACK_UNKNOWN_TYPE);
    send(&c, BPROTO_MSG_PANEL_STATE, 6, NULL, 0);
    CHECK(reply_code(6) == BPROTO_NACK_UNKNOWN_TYPE);

    uint8_t p[80];
    uint32_t table[6] = {1000, 2000, 4000, 8000, 16000, 32000};
    size_t len = brackets(p, 45454u, 6, table);
    send(&c, BPROTO_MSG_SET_BRACKETS, 7, p, len - 1); /* length does not match n */
    CHECK(reply_code(7) == BPROTO_NACK_BAD_LENGTH);
    send(&c, BPROTO_MSG_SET_BRACKETS, 8, p, 3);
    CHECK(reply_code(8) == BPROTO_NACK_BAD_LENGTH);
    send(&c, BPROTO_MSG_SET_BRACKETS, 9, brackets(p, 45454u, 1, (uint32_t[]){45300}) ? p : p, 9);
    CHECK(reply_code(9) == BPROTO_NACK_BAD_VALUE);
    send(&c, BPROTO_MSG_SET_BRACKETS, 10, p, brackets(p, 999u, 1, (uint32_t[]){10}));
    CHECK(reply_code(10) == BPROTO_NACK_BAD_VALUE);
    send(&c, BPROTO_MSG_SET_BRACKETS, 11, p, brackets(p, 45454u, 0, table));
    CHECK(reply_code(11) == BPROTO_NACK_BAD_VALUE);
    uint32_t many[17] = {0};
    for (int i = 0; i < 17; i++) many[i] = 100;
    send(&c, BPROTO_MSG_SET_BRACKETS, 12, p, brackets(p, 45454u, 17, many));
    CHECK(reply_code(12) == BPROTO_NACK_BAD_VALUE);
    send(&c, BPROTO_MSG_SET_BRACKETS, 13, p, brackets(p, 45454u, 6, table));
    CHECK(reply_code(13) == 0);
    CHECK(c.table.n == 6 && c.table.period_us == 45454u && c.table.exposure_us[5] == 32000u);

    uint8_t sess[4];
    bproto_put_u32(sess, 77);
    send(&c, BPROTO_MSG_START, 14, sess, 3);
    CHECK(reply_code(14) == BPROTO_NACK_BAD_LENGTH);
    send(&c, BPROTO_MSG_START, 15, sess, 4);
    CHECK(reply_code(15) == 0 && timer_running && start_calls == 1 && started.n == 6);
    send(&c, BPROTO_MSG_START, 16, sess, 4); /* same session: ACK, no restart */
    CHECK(reply_code(16) == 0 && start_calls == 1);
    bproto_put_u32(sess, 78);
    send(&c, BPROTO_MSG_START, 17, sess, 4);
    CHECK(reply_code(17) == BPROTO_NACK_BAD_STATE);
    send(&c, BPROTO_MSG_SET_BRACKETS, 18, p, brackets(p, 45454u, 6, table));
    CHECK(reply_code(18) == BPROTO_NACK_BAD_STATE);

    /* pulses: the returned width is the NEXT pulse's (interrupt reload path) */
    for (uint32_t k = 0; k < 13; k++) {
        uint32_t next = trig_core_on_pulse(&c, 1000000ull + 45454ull * k);
        CHECK(next == table[(k + 1) % 6]);
    }
    trig_core_poll(&c, 100);
    collect();
    int ev = 0;
    for (int i = 0; i < n_msgs; i++) {
        if (msgs[i].type != BPROTO_MSG_TRIGGER) continue;
        const uint8_t *q = msgs[i].p;
        CHECK(bproto_get_u32(q) == 77u);
        CHECK(bproto_get_u32(q + 4) == (uint32_t)ev);
        CHECK(q[8] == ev % 6);
        CHECK(bproto_get_u32(q + 9) == table[ev % 6]);
        CHECK(bproto_get_u64(q + 13) == 1000000ull + 45454ull * (uint64_t)ev);
        ev++;
    }
    CHECK(ev == 13);

    /* events of pulses before STOP precede its ACK; STOP is idempotent; no events afterwards */
    (void)trig_core_on_pulse(&c, 5);
    send(&c, BPROTO_MSG_STOP, 19, NULL, 0);
    collect();
    CHECK(n_msgs == 2 && msgs[0].type == BPROTO_MSG_TRIGGER && msgs[1].type == BPROTO_MSG_ACK);
    CHECK(!timer_running);
    CHECK(trig_core_on_pulse(&c, 6) == 0u);
    send(&c, BPROTO_MSG_STOP, 20, NULL, 0);
    CHECK(reply_code(20) == 0);
    send(&c, BPROTO_MSG_STOP, 21, sess, 1);
    CHECK(reply_code(21) == BPROTO_NACK_BAD_LENGTH);

    /* garbage and a corrupted frame are ignored, the next command is answered */
    const uint8_t garbage[] = {0x00, 0x13, 0x37, 0xFF, 0x00, 0x05, 0x01, 0x02, 0x00};
    for (size_t i = 0; i < sizeof(garbage); i++) trig_core_rx_byte(&c, garbage[i]);
    uint8_t frame[BPROTO_MAX_FRAME];
    size_t fn = bproto_encode_frame(BPROTO_MSG_STOP, 22, NULL, 0, frame, sizeof(frame));
    frame[2] ^= 0x40; /* corrupt */
    for (size_t i = 0; i < fn; i++) trig_core_rx_byte(&c, frame[i]);
    collect();
    CHECK(n_msgs == 0);
    send(&c, BPROTO_MSG_STOP, 23, NULL, 0);
    CHECK(reply_code(23) == 0);

    /* restart: trigger_seq starts again at 0 */
    bproto_put_u32(sess, 79);
    send(&c, BPROTO_MSG_START, 24, sess, 4);
    CHECK(reply_code(24) == 0);
    (void)trig_core_on_pulse(&c, 1);
    trig_core_poll(&c, 100);
    collect();
    CHECK(n_msgs >= 1 && msgs[0].type == BPROTO_MSG_TRIGGER && bproto_get_u32(msgs[0].p + 4) == 0u);

    /* queue overflow while TX is blocked: events are dropped but trigger_seq keeps counting (host sees a gap) */
    tx_cap = 0;
    for (uint32_t k = 0; k < TRIG_EVENT_QUEUE_LEN + 5; k++) (void)trig_core_on_pulse(&c, 10 + k);
    trig_core_poll(&c, 200);
    CHECK(c.events_dropped == 5);
    tx_cap = sizeof(tx);
    trig_core_poll(&c, 300);
    collect();
    int trig = 0;
    uint32_t last_seq = 0;
    for (int i = 0; i < n_msgs; i++) {
        if (msgs[i].type == BPROTO_MSG_TRIGGER) {
            trig++;
            last_seq = bproto_get_u32(msgs[i].p + 4);
        }
    }
    CHECK(trig == (int)TRIG_EVENT_QUEUE_LEN && last_seq == TRIG_EVENT_QUEUE_LEN);
    (void)trig_core_on_pulse(&c, 99);
    trig_core_poll(&c, 301);
    collect();
    CHECK(n_msgs >= 1 && bproto_get_u32(msgs[0].p + 4) == TRIG_EVENT_QUEUE_LEN + 6);

    /* heartbeat every 500 ms with the state */
    tx_len = 0;
    trig_core_poll(&c, 1000);
    collect();
    CHECK(n_msgs == 1 && msgs[0].type == BPROTO_MSG_HEARTBEAT && msgs[0].p[4] == 1);
    trig_core_poll(&c, 1200);
    collect();
    CHECK(n_msgs == 0);
}

int main(void)
{
    test_timeext();
    test_validation();
    test_protocol();
    if (failures) {
        fprintf(stderr, "%d check(s) failed\n", failures);
        return 1;
    }
    printf("trigger core: all checks passed\n");
    return 0;
}
