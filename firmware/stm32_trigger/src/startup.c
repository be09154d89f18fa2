/*
 * startup.c - vector table and reset handler of the STM32F407 (82 device interrupts), fault handlers that force
 * the trigger outputs inactive and wait for the watchdog.
 */
#include <stdint.h>
#include <string.h>

#include "hal_stm32.h"

extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _estack;
int main(void);

void Reset_Handler(void);
void Fault_Handler(void);
void Default_Handler(void);
void SysTick_Handler(void);
void TIM3_IRQHandler(void);
void USART2_IRQHandler(void);

void Reset_Handler(void)
{
    uint32_t *src = &_sidata;
    for (uint32_t *dst = &_sdata; dst < &_edata;) {
        *dst++ = *src++;
    }
    for (uint32_t *dst = &_sbss; dst < &_ebss;) {
        *dst++ = 0u;
    }
    (void)main();
    Fault_Handler();
}

/* Any fault: outputs inactive, interrupts off, wait for the independent watchdog to reset the chip. */
void Fault_Handler(void)
{
    __asm volatile("cpsid i");
    hal_outputs_inactive();
    for (;;) {
    }
}

/* An interrupt nobody asked for is a fault too. */
void Default_Handler(void)
{
    Fault_Handler();
}

#define IRQ_COUNT 82
#define VEC(irq) (16 + (irq))
typedef void (*vector_t)(void);

__attribute__((section(".isr_vector"), used)) const vector_t vector_table[16 + IRQ_COUNT] = {
    [0] = (vector_t)(uintptr_t)&_estack,
    [1] = Reset_Handler,
    [2] = Fault_Handler,              /* NMI */
    [3] = Fault_Handler,              /* HardFault */
    [4] = Fault_Handler,              /* MemManage */
    [5] = Fault_Handler,              /* BusFault */
    [6] = Fault_Handler,              /* UsageFault */
    [11] = Default_Handler,           /* SVCall */
    [12] = Default_Handler,           /* DebugMon */
    [14] = Default_Handler,           /* PendSV */
    [15] = SysTick_Handler,
    [VEC(0)... VEC(28)] = Default_Handler,
    [VEC(29)] = TIM3_IRQHandler,
    [VEC(30)... VEC(37)] = Default_Handler,
    [VEC(38)] = USART2_IRQHandler,
    [VEC(39)... VEC(IRQ_COUNT - 1)] = Default_Handler,
};
