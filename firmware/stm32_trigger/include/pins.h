/*
 * pins.h - every pin the STM32F407 trigger firmware uses (single source of truth for the firmware;
 * hw/wiring.yaml documents the same assignment and a test checks that both agree).
 *
 * Format (read by the hw/ consistency test): `#define PIN_<SIGNAL> PIN('<PORT>', <NUMBER>)`, plus
 * `#define PIN_<SIGNAL>_AF <n>` for pins driven by an alternate function.
 *
 * Choice of pins (STM32F4-Discovery compatible: PB0/PB1 are free there, PA2/PA3 are free, PD12 is the green LED):
 *   - both camera trigger outputs come from ONE timer (TIM3 channels 3 and 4) so they are in lockstep;
 *   - host link on USART2 (PA2 TX, PA3 RX), the ST-LINK virtual COM port on Nucleo boards.
 */
#ifndef PINS_H
#define PINS_H

/* PIN(port letter, number) -> 16-bit code: high byte = port index (A=0), low byte = pin number. */
#define PIN(port, num) ((unsigned)((((port) - 'A') << 8) | (num)))
#define PIN_PORT(pin) ((pin) >> 8)
#define PIN_NUM(pin) ((pin) & 0xFFu)

/* Host link: USART2, 921600 8N1, AF7. */
#define PIN_USART2_TX PIN('A', 2)
#define PIN_USART2_TX_AF 7
#define PIN_USART2_RX PIN('A', 3)
#define PIN_USART2_RX_AF 7

/* Camera triggers: TIM3_CH3 (left) and TIM3_CH4 (right), AF2. Pulse width = exposure time. */
#define PIN_TRIG_LEFT PIN('B', 0)
#define PIN_TRIG_LEFT_AF 2
#define PIN_TRIG_RIGHT PIN('B', 1)
#define PIN_TRIG_RIGHT_AF 2

/* Status LED (plain GPIO output, active high): on while running (START), off when idle. */
#define PIN_STATUS_LED PIN('D', 12)

#endif /* PINS_H */
