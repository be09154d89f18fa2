/* trigger_types.h - plain data shared by the trigger core and the HAL. */
#ifndef TRIGGER_TYPES_H
#define TRIGGER_TYPES_H

#include <stdint.h>

#include "bproto.h"

/* Bracket table capacity: the SET_BRACKETS value rule of the wire codec (bproto_check_set_brackets). */
#define TRIG_MAX_BRACKETS BPROTO_MAX_BRACKETS

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
