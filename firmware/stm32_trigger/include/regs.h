/*
 * regs.h - the STM32F407 registers this firmware uses, written by hand from RM0090 (no vendor HAL here).
 * Only what the firmware touches: RCC, FLASH, PWR, GPIO, USART2, TIM3, TIM5, DMA1, IWDG, SysTick, NVIC, SCB, UID.
 */
#ifndef REGS_H
#define REGS_H

#include <stdint.h>

#define REG32(addr) (*(volatile uint32_t *)(uintptr_t)(addr))

/* ---- RCC (0x40023800) ---- */
#define RCC_BASE 0x40023800u
#define RCC_CR REG32(RCC_BASE + 0x00u)
#define RCC_PLLCFGR REG32(RCC_BASE + 0x04u)
#define RCC_CFGR REG32(RCC_BASE + 0x08u)
#define RCC_AHB1ENR REG32(RCC_BASE + 0x30u)
#define RCC_APB1ENR REG32(RCC_BASE + 0x40u)
#define RCC_CSR REG32(RCC_BASE + 0x74u)
#define RCC_CR_HSION (1u << 0)
#define RCC_CR_HSIRDY (1u << 1)
#define RCC_CR_HSEON (1u << 16)
#define RCC_CR_HSERDY (1u << 17)
#define RCC_CR_PLLON (1u << 24)
#define RCC_CR_PLLRDY (1u << 25)
#define RCC_PLLCFGR_SRC_HSE (1u << 22)
#define RCC_CFGR_SW_MASK 3u
#define RCC_CFGR_SW_HSI 0u
#define RCC_CFGR_SW_PLL 2u
#define RCC_CFGR_SWS_MASK (3u << 2)
#define RCC_CFGR_SWS_PLL (2u << 2)
#define RCC_CFGR_PPRE1_DIV4 (5u << 10)
#define RCC_CFGR_PPRE2_DIV2 (4u << 13)
#define RCC_AHB1ENR_GPIOAEN (1u << 0)
#define RCC_AHB1ENR_GPIOBEN (1u << 1)
#define RCC_AHB1ENR_GPIODEN (1u << 3)
#define RCC_AHB1ENR_DMA1EN (1u << 21)
#define RCC_APB1ENR_TIM3EN (1u << 1)
#define RCC_APB1ENR_TIM5EN (1u << 3)
#define RCC_APB1ENR_USART2EN (1u << 17)
#define RCC_APB1ENR_PWREN (1u << 28)
#define RCC_CSR_RMVF (1u << 24)
#define RCC_CSR_IWDGRSTF (1u << 29)

/* ---- FLASH interface (0x40023C00) ---- */
#define FLASH_ACR REG32(0x40023C00u)
#define FLASH_ACR_LATENCY_5WS 5u
#define FLASH_ACR_PRFTEN (1u << 8)
#define FLASH_ACR_ICEN (1u << 9)
#define FLASH_ACR_DCEN (1u << 10)

/* ---- GPIO (port A = 0x40020000, one port every 0x400) ---- */
#define GPIO_BASE(port) (0x40020000u + 0x400u * (uint32_t)(port))
#define GPIO_MODER(port) REG32(GPIO_BASE(port) + 0x00u)
#define GPIO_OTYPER(port) REG32(GPIO_BASE(port) + 0x04u)
#define GPIO_OSPEEDR(port) REG32(GPIO_BASE(port) + 0x08u)
#define GPIO_PUPDR(port) REG32(GPIO_BASE(port) + 0x0Cu)
#define GPIO_ODR(port) REG32(GPIO_BASE(port) + 0x14u)
#define GPIO_BSRR(port) REG32(GPIO_BASE(port) + 0x18u)
#define GPIO_AFR(port, i) REG32(GPIO_BASE(port) + 0x20u + 4u * (uint32_t)(i))
#define GPIO_MODE_INPUT 0u
#define GPIO_MODE_OUTPUT 1u
#define GPIO_MODE_AF 2u

/* ---- USART2 (0x40004400) ---- */
#define USART2_BASE 0x40004400u
#define USART2_SR REG32(USART2_BASE + 0x00u)
#define USART2_DR REG32(USART2_BASE + 0x04u)
#define USART2_BRR REG32(USART2_BASE + 0x08u)
#define USART2_CR1 REG32(USART2_BASE + 0x0Cu)
#define USART2_CR2 REG32(USART2_BASE + 0x10u)
#define USART2_CR3 REG32(USART2_BASE + 0x14u)
#define USART_SR_ORE (1u << 3)
#define USART_SR_RXNE (1u << 5)
#define USART_SR_TXE (1u << 7)
#define USART_CR1_RE (1u << 2)
#define USART_CR1_TE (1u << 3)
#define USART_CR1_RXNEIE (1u << 5)
#define USART_CR1_TXEIE (1u << 7)
#define USART_CR1_UE (1u << 13)

/* ---- General-purpose timers TIM3 (16-bit, 0x40000400) and TIM5 (32-bit, 0x40000C00) ---- */
#define TIM3_BASE 0x40000400u
#define TIM5_BASE 0x40000C00u
#define TIM_CR1(b) REG32((b) + 0x00u)
#define TIM_CR2(b) REG32((b) + 0x04u)
#define TIM_DIER(b) REG32((b) + 0x0Cu)
#define TIM_SR(b) REG32((b) + 0x10u)
#define TIM_EGR(b) REG32((b) + 0x14u)
#define TIM_CCMR2(b) REG32((b) + 0x1Cu)
#define TIM_CCER(b) REG32((b) + 0x20u)
#define TIM_CNT(b) REG32((b) + 0x24u)
#define TIM_PSC(b) REG32((b) + 0x28u)
#define TIM_ARR(b) REG32((b) + 0x2Cu)
#define TIM_CCR3(b) REG32((b) + 0x3Cu)
#define TIM_CCR4(b) REG32((b) + 0x40u)
#define TIM_DCR(b) REG32((b) + 0x48u)
#define TIM_DMAR(b) REG32((b) + 0x4Cu)
#define TIM_DMAR_ADDR(b) ((b) + 0x4Cu)
#define TIM_CR1_CEN (1u << 0)
#define TIM_CR1_URS (1u << 2)
#define TIM_CR1_ARPE (1u << 7)
#define TIM_DIER_UIE (1u << 0)
#define TIM_DIER_UDE (1u << 8)
#define TIM_SR_UIF (1u << 0)
#define TIM_EGR_UG (1u << 0)
/* CCMR2: channel 3 in bits 0..7, channel 4 in bits 8..15. OCxM: 100 force inactive, 110 PWM mode 1. */
#define TIM_CCMR2_OC3PE (1u << 3)
#define TIM_CCMR2_OC3M_SHIFT 4u
#define TIM_CCMR2_OC4PE (1u << 11)
#define TIM_CCMR2_OC4M_SHIFT 12u
#define TIM_OCM_FORCE_INACTIVE 4u
#define TIM_OCM_PWM1 6u
#define TIM_CCER_CC3E (1u << 8)
#define TIM_CCER_CC3P (1u << 9)
#define TIM_CCER_CC4E (1u << 12)
#define TIM_CCER_CC4P (1u << 13)
#define TIM_DCR_DBA_CCR3 15u /* (0x3C / 4): DMA burst starts at CCR3 */
#define TIM_DCR_DBL_SHIFT 8u

/* ---- DMA1 (0x40026000): TIM3_UP is stream 2, channel 5 (RM0090 table 42) ---- */
#define DMA1_BASE 0x40026000u
#define DMA1_LIFCR REG32(DMA1_BASE + 0x08u)
#define DMA_S_CR(n) REG32(DMA1_BASE + 0x10u + 0x18u * (uint32_t)(n))
#define DMA_S_NDTR(n) REG32(DMA1_BASE + 0x14u + 0x18u * (uint32_t)(n))
#define DMA_S_PAR(n) REG32(DMA1_BASE + 0x18u + 0x18u * (uint32_t)(n))
#define DMA_S_M0AR(n) REG32(DMA1_BASE + 0x1Cu + 0x18u * (uint32_t)(n))
#define DMA_S_FCR(n) REG32(DMA1_BASE + 0x24u + 0x18u * (uint32_t)(n))
#define DMA_CR_EN (1u << 0)
#define DMA_CR_DIR_M2P (1u << 6)
#define DMA_CR_CIRC (1u << 8)
#define DMA_CR_MINC (1u << 10)
#define DMA_CR_PSIZE_32 (2u << 11)
#define DMA_CR_MSIZE_32 (2u << 13)
#define DMA_CR_PL_HIGH (2u << 16)
#define DMA_CR_CHSEL_SHIFT 25u
#define DMA_LIFCR_STREAM2_ALL (0x3Du << 16)

/* ---- IWDG (0x40003000) ---- */
#define IWDG_KR REG32(0x40003000u)
#define IWDG_PR REG32(0x40003004u)
#define IWDG_RLR REG32(0x40003008u)

/* ---- Cortex-M4 core ---- */
#define SYST_CSR REG32(0xE000E010u)
#define SYST_RVR REG32(0xE000E014u)
#define SYST_CVR REG32(0xE000E018u)
#define NVIC_ISER(i) REG32(0xE000E100u + 4u * (uint32_t)(i))
#define NVIC_IPR8(irq) (*(volatile uint8_t *)(uintptr_t)(0xE000E400u + (uint32_t)(irq)))
#define SCB_AIRCR REG32(0xE000ED0Cu)

/* ---- Device electronic signature: 96-bit unique ID ---- */
#define UID_BASE 0x1FFF7A10u

/* IRQ numbers (RM0090 vector table) */
#define IRQ_DMA1_STREAM2 13
#define IRQ_TIM3 29
#define IRQ_USART2 38
#define IRQ_TIM5 50

#endif /* REGS_H */
