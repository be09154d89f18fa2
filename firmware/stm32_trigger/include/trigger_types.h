/* trigger_types.h - plain data shared by the trigger core and the HAL. */
#ifndef TRIGGER_TYPES_H
#define TRIGGER_TYPES_H

#include <stdint.h>

#define TRIG_MAX_BRACKETS 16u
/* SET_BRACKETS bounds (wire protocol v1, firmware/protocol/PROTOCOL.md). */
#define TRIG_PERIOD_MIN_US 1000u
#define TRIG_PERIOD_MAX_US 1000000u
#define TRIG_EXPOSURE_MIN_US 10u
#define TRIG_GAP_MIN_US 200u /* exposure_us + 200 <= period_us */

/* A bracket table: pulses repeat every period_us; pulse k has width exposure_us[k % n]. */
typedef struct {
    uint32_t period_us;
    uint8_t n;
    uint32_t exposure_us[TRIG_MAX_BRACKETS];
} trig_table_t;

/* One pulse, as reported in a TRIGGER message. */
typedef struct {
    uint32_t session_id;
    uint32_t trigger_seq;
    uint8_t bracket_index;
    uint32_t exposure_us;
    uint64_t t_start_us;
} trig_event_t;

#endif /* TRIGGER_TYPES_H */
