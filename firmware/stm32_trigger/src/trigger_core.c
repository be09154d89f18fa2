/*
 * trigger_core.c - protocol dispatch, validation, bracket scheduler, event queue and heartbeat of the trigger.
 * Portable C99: talks to the hardware only through hal.h.
 */
#include "trigger_core.h"

#include <string.h>

#include "hal.h"

static const uint32_t default_exposures_us[6] = {1000u, 2000u, 4000u, 8000u, 16000u, 32000u};

void trig_timeext_init(trig_timeext_t *t, uint32_t raw)
{
    t->last_raw = raw;
    t->high = 0u;
}

uint64_t trig_timeext_extend(trig_timeext_t *t, uint32_t raw)
{
    if (raw < t->last_raw) {
        t->high += (uint64_t)1u << 32;
    }
    t->last_raw = raw;
    return t->high | (uint64_t)raw;
}

uint8_t trig_sched_index(uint32_t k, uint8_t n)
{
    return (uint8_t)(n ? k % n : 0u);
}

void trig_core_init(trig_core_t *c, uint32_t capabilities)
{
    memset(c, 0, sizeof(*c));
    bproto_decoder_init(&c->dec);
    c->table.period_us = 45454u;
    c->table.n = 6u;
    memcpy(c->table.exposure_us, default_exposures_us, sizeof(default_exposures_us));
    c->capabilities = capabilities;
}

static int send_frame(trig_core_t *c, uint8_t type, const uint8_t *payload, size_t len)
{
    uint8_t out[BPROTO_MAX_FRAME];
    size_t n = bproto_encode_frame(type, c->tx_seq, payload, len, out, sizeof(out));
    if (n == 0u || hal_uart_write(out, n) != n) {
        c->frames_dropped_tx++;
        return 0;
    }
    c->tx_seq++;
    return 1;
}

/* Payloads are built by the codec's pack functions (bproto.h), never at hand-coded offsets; a pack that fails
 * (cannot happen for these fixed layouts) counts as a dropped frame. */
static int send_packed(trig_core_t *c, uint8_t type, const uint8_t *payload, int len)
{
    if (len < 0) {
        c->frames_dropped_tx++;
        return 0;
    }
    return send_frame(c, type, payload, (size_t)len);
}

static void send_ack(trig_core_t *c, uint16_t acked_seq)
{
    const bproto_ack_t m = {acked_seq};
    uint8_t p[BPROTO_LEN_ACK];
    (void)send_packed(c, BPROTO_MSG_ACK, p, bproto_pack_ack(&m, p, sizeof(p)));
}

static void send_nack(trig_core_t *c, uint16_t acked_seq, uint8_t code)
{
    const bproto_nack_t m = {acked_seq, code};
    uint8_t p[BPROTO_LEN_NACK];
    (void)send_packed(c, BPROTO_MSG_NACK, p, bproto_pack_nack(&m, p, sizeof(p)));
}

static void send_hello(trig_core_t *c)
{
    bproto_hello_t m;
    uint8_t p[BPROTO_LEN_HELLO];
    m.device_kind = TRIG_DEVICE_KIND;
    m.proto_minor = TRIG_PROTO_MINOR;
    m.fw_major = TRIG_FW_MAJOR;
    m.fw_minor = TRIG_FW_MINOR;
    m.fw_patch = TRIG_FW_PATCH;
    hal_uid(m.uid);
    m.capabilities = c->capabilities;
    (void)send_packed(c, BPROTO_MSG_HELLO, p, bproto_pack_hello(&m, p, sizeof(p)));
}

static void send_heartbeat(trig_core_t *c, uint32_t now_ms)
{
    bproto_heartbeat_t m;
    uint8_t p[BPROTO_LEN_HEARTBEAT];
    m.uptime_ms = now_ms;
    m.state = c->running ? 1u : 0u;
    (void)send_packed(c, BPROTO_MSG_HEARTBEAT, p, bproto_pack_heartbeat(&m, p, sizeof(p)));
}

/* Send queued TRIGGER events in order; an event that does not fit the TX buffer stays queued. */
static void drain_events(trig_core_t *c)
{
    while (c->q_tail != c->q_head) {
        const trig_event_t *e = &c->queue[c->q_tail % TRIG_EVENT_QUEUE_LEN];
        bproto_trigger_t m;
        uint8_t p[BPROTO_LEN_TRIGGER];
        m.session_id = e->session_id;
        m.trigger_seq = e->trigger_seq;
        m.bracket_index = e->bracket_index;
        m.exposure_us = e->exposure_us;
        m.t_start_us = e->t_start_us;
        int len = bproto_pack_trigger(&m, p, sizeof(p));
        uint8_t out[BPROTO_MAX_FRAME];
        size_t n = len < 0 ? 0u : bproto_encode_frame(BPROTO_MSG_TRIGGER, c->tx_seq, p, (size_t)len, out, sizeof(out));
        if (n == 0u || hal_uart_write(out, n) != n) {
            return; /* retry on the next poll */
        }
        c->tx_seq++;
        c->q_tail++;
    }
}

static void stop(trig_core_t *c)
{
    uint32_t s = hal_irq_save();
    c->running = 0u;
    hal_trigger_stop();
    hal_irq_restore(s);
    hal_led(0);
}

static void handle_set_brackets(trig_core_t *c, const bproto_frame_t *f)
{
    bproto_set_brackets_t m;
    uint8_t code = bproto_unpack_set_brackets(f->payload, f->len, &m); /* BAD_LENGTH unless 5 + 4 n bytes */
    if (code != 0u) {
        send_nack(c, f->seq, code);
        return;
    }
    if (c->running) {
        send_nack(c, f->seq, BPROTO_NACK_BAD_STATE);
        return;
    }
    if (bproto_check_set_brackets(m.period_us, m.exposures_us, m.n) != 0u) { /* the codec owns the rule */
        send_nack(c, f->seq, BPROTO_NACK_BAD_VALUE);
        return;
    }
    c->table.period_us = m.period_us;
    c->table.n = m.n;
    memcpy(c->table.exposure_us, m.exposures_us, sizeof(uint32_t) * m.n);
    send_ack(c, f->seq);
}

static void handle_start(trig_core_t *c, const bproto_frame_t *f)
{
    bproto_start_t m;
    uint8_t code = bproto_unpack_start(f->payload, f->len, &m);
    if (code != 0u) {
        send_nack(c, f->seq, code);
        return;
    }
    uint32_t session_id = m.session_id;
    if (c->running) {
        if (session_id == c->session_id) {
            send_ack(c, f->seq); /* repeated START of the same session: no restart */
        } else {
            send_nack(c, f->seq, BPROTO_NACK_BAD_STATE);
        }
        return;
    }
    drain_events(c); /* leftovers of the previous session go first */
    uint32_t s = hal_irq_save();
    c->session_id = session_id;
    c->next_seq = 0u;
    c->running = 1u;
    hal_irq_restore(s);
    send_ack(c, f->seq); /* the ACK precedes the first TRIGGER event */
    hal_led(1);
    hal_trigger_start(&c->table);
}

void trig_core_handle_frame(trig_core_t *c, const bproto_frame_t *f)
{
    if (f->ver != BPROTO_VERSION) {
        c->unsupported_version++;
        return;
    }
    switch (f->type) {
    case BPROTO_MSG_HELLO:
        if (f->len != 0u) { /* another device's HELLO, or garbage: not a request */
            send_nack(c, f->seq, BPROTO_NACK_BAD_LENGTH);
        } else {
            send_hello(c);
        }
        break;
    case BPROTO_MSG_PING: {
        bproto_ping_t ping;
        uint8_t code = bproto_unpack_ping(f->payload, f->len, &ping);
        if (code != 0u) {
            send_nack(c, f->seq, code);
            break;
        }
        bproto_pong_t pong;
        uint8_t p[BPROTO_LEN_PONG];
        pong.host_time_ns = ping.host_time_ns;
        pong.device_time_us = hal_time_us();
        (void)send_packed(c, BPROTO_MSG_PONG, p, bproto_pack_pong(&pong, p, sizeof(p)));
        break;
    }
    case BPROTO_MSG_SET_BRACKETS:
        handle_set_brackets(c, f);
        break;
    case BPROTO_MSG_START:
        handle_start(c, f);
        break;
    case BPROTO_MSG_STOP: {
        uint8_t code = bproto_unpack_stop(f->payload, f->len);
        if (code != 0u) {
            send_nack(c, f->seq, code);
            break;
        }
        stop(c);
        drain_events(c); /* events of pulses that happened before STOP precede its ACK */
        send_ack(c, f->seq);
        break;
    }
    case BPROTO_MSG_HEARTBEAT: /* host heartbeat: no reply */
    case BPROTO_MSG_ACK:
    case BPROTO_MSG_NACK:
        break;
    default:
        send_nack(c, f->seq, BPROTO_NACK_UNKNOWN_TYPE);
        break;
    }
}

void trig_core_rx_byte(trig_core_t *c, uint8_t byte)
{
    bproto_frame_t f;
    if (bproto_decoder_feed(&c->dec, byte, &f)) {
        trig_core_handle_frame(c, &f);
    }
}

void trig_core_boot(trig_core_t *c, uint32_t now_ms)
{
    send_hello(c);
    c->last_heartbeat_ms = now_ms;
}

void trig_core_poll(trig_core_t *c, uint32_t now_ms)
{
    drain_events(c);
    if ((uint32_t)(now_ms - c->last_heartbeat_ms) >= TRIG_HEARTBEAT_PERIOD_MS) {
        c->last_heartbeat_ms = now_ms;
        send_heartbeat(c, now_ms);
    }
}

uint32_t trig_core_on_pulse(trig_core_t *c, uint64_t t_start_us)
{
    uint8_t n = c->table.n;
    if (!c->running || n == 0u) {
        return 0u;
    }
    uint32_t k = c->next_seq++;
    uint8_t idx = trig_sched_index(k, n);
    if (c->q_head - c->q_tail < TRIG_EVENT_QUEUE_LEN) {
        trig_event_t *e = &c->queue[c->q_head % TRIG_EVENT_QUEUE_LEN];
        e->session_id = c->session_id;
        e->trigger_seq = k;
        e->bracket_index = idx;
        e->exposure_us = c->table.exposure_us[idx];
        e->t_start_us = t_start_us;
        c->q_head++;
    } else {
        c->events_dropped++;
    }
    return c->table.exposure_us[trig_sched_index(k + 1u, n)];
}
