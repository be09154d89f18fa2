/*
 * trigger_core.h - portable logic of the trigger: protocol dispatch, validation, bracket scheduler, event queue,
 * heartbeat, and the 32->64-bit time extension. No register access here (see hal.h), so it compiles for the host.
 */
#ifndef TRIGGER_CORE_H
#define TRIGGER_CORE_H

#include <stdint.h>

#include "bproto.h"
#include "trigger_types.h"

#define TRIG_FW_MAJOR 0u
#define TRIG_FW_MINOR 1u
#define TRIG_FW_PATCH 0u
#define TRIG_DEVICE_KIND 1u
#define TRIG_PROTO_MINOR 0u
#define TRIG_HEARTBEAT_PERIOD_MS 500u
#define TRIG_EVENT_QUEUE_LEN 32u /* power of two */

/* HELLO capabilities bitfield. */
#define TRIG_CAP_DMA_RELOAD (1u << 0) /* widths reloaded by DMA on the update event (else by the update interrupt) */
#define TRIG_CAP_PLL_168MHZ (1u << 1) /* HSE 8 MHz -> PLL 168 MHz locked (else HSI 16 MHz fallback) */
#define TRIG_CAP_EMULATED (1u << 2)   /* RCC not modelled: running in an emulator (QEMU) */
#define TRIG_CAP_WATCHDOG (1u << 3)   /* independent watchdog running */
#define TRIG_CAP_ACTIVE_LOW (1u << 4) /* exposure while the output is low (camera triggers on the falling edge) */
#define TRIG_CAP_IWDG_RESET (1u << 5) /* the last reset came from the watchdog */

/* Software extension of a wrapping 32-bit counter to 64 bits. Call at least once per wrap period. */
typedef struct {
    uint32_t last_raw;
    uint64_t high; /* multiples of 2^32 already elapsed */
} trig_timeext_t;

void trig_timeext_init(trig_timeext_t *t, uint32_t raw);
uint64_t trig_timeext_extend(trig_timeext_t *t, uint32_t raw);

/* Bracket index of pulse number k (k = trigger_seq) in a table of n entries. */
uint8_t trig_sched_index(uint32_t k, uint8_t n);

typedef struct {
    bproto_decoder_t dec;
    trig_table_t table;
    volatile uint8_t running;
    uint32_t session_id;
    volatile uint32_t next_seq; /* trigger_seq of the next pulse */
    trig_event_t queue[TRIG_EVENT_QUEUE_LEN];
    volatile uint32_t q_head; /* written by the pulse interrupt */
    volatile uint32_t q_tail; /* written by the main loop */
    uint32_t events_dropped;  /* queue full: trigger_seq still advances, the host sees the gap */
    uint32_t frames_dropped_tx;
    uint32_t unsupported_version;
    uint16_t tx_seq;
    uint32_t last_heartbeat_ms;
    uint32_t capabilities;
} trig_core_t;

/* Reset the core to idle with the default table (period 45454 us, 1,2,4,8,16,32 ms). */
void trig_core_init(trig_core_t *c, uint32_t capabilities);
/* Announce the device: unsolicited HELLO (lets the host detect a reboot). */
void trig_core_boot(trig_core_t *c, uint32_t now_ms);
/* Feed one received byte (main loop). */
void trig_core_rx_byte(trig_core_t *c, uint8_t byte);
/* Dispatch one decoded frame (main loop). */
void trig_core_handle_frame(trig_core_t *c, const bproto_frame_t *f);
/* Main-loop work: send queued TRIGGER events, the 2 Hz heartbeat. */
void trig_core_poll(trig_core_t *c, uint32_t now_ms);
/* Pulse-start hook (interrupt context): records pulse k = trigger_seq started at t_start_us; returns the width of
 * pulse k+1, which the interrupt reload path writes into the preloaded compare registers. */
uint32_t trig_core_on_pulse(trig_core_t *c, uint64_t t_start_us);

#endif /* TRIGGER_CORE_H */
