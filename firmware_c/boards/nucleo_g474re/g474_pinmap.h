/**
 * @file g474_pinmap.h
 * @brief The one place a NUCLEO-G474RE drive is adapted to its power stage:
 *        pins, alternate functions, ADC channels, the sensing scale, the CAN
 *        bitrate and node id, the reference scale. NOT YET TESTED ON SILICON.
 *
 * Default: ST's X-NUCLEO-IHM08M1 (L6398 gate drivers, STL220N6F7 60 V
 * MOSFETs, three 10 mOhm low-side shunts amplified by a TSV994, overcurrent
 * comparator on the break input) stacked on the NUCLEO's ST morpho
 * connectors, jumpered for three-shunt sensing. Its morpho pin use is the one
 * ST's motor-control SDK gives for the Nucleo-64 boards (PWM on PA8/PA9/PA10
 * and PA7/PB0/PB1, currents on PA0/PC1/PC0, bus voltage on PA1, encoder/Hall
 * connector J3 on PA15/PB3/PB10, overcurrent on PA6). Alternate-function
 * numbers and ADC channels are the STM32G474RE's (datasheet DS12288, table
 * "alternate functions"; RM0440 "ADC1/2/3/4/5 connectivity" for the channel numbers).
 *
 * Another power stage: change the macros below (every one is read by
 * g474_port.c only), check each new pin's alternate function in the
 * datasheet, and re-derive the three scale factors from its schematic. A
 * build with -DG474_POWER_STAGE_CUSTOM=1 skips the IHM08M1 defaults so that a
 * header of your own (-include my_stage.h) can provide every macro.
 *
 * Values marked VERIFY come from the power stage's documentation, not from a
 * measurement: docs/hardware_bringup.md says how to measure each one.
 */
#ifndef PMLSM_G474_PINMAP_H
#define PMLSM_G474_PINMAP_H

#ifndef G474_POWER_STAGE_CUSTOM

/* ---- ports: index 0 = GPIOA, 1 = GPIOB, 2 = GPIOC ... (RM0440 "GPIO") ---- */
#define G474_PA 0u
#define G474_PB 1u
#define G474_PC 2u

/* ---- PWM: TIM1, three complementary pairs (DS12288 AF6 on all six) ---- */
#define G474_PWM_UH_PORT G474_PA /* TIM1_CH1 */
#define G474_PWM_UH_PIN 8u
#define G474_PWM_VH_PORT G474_PA /* TIM1_CH2 */
#define G474_PWM_VH_PIN 9u
#define G474_PWM_WH_PORT G474_PA /* TIM1_CH3 */
#define G474_PWM_WH_PIN 10u
#define G474_PWM_UL_PORT G474_PA /* TIM1_CH1N */
#define G474_PWM_UL_PIN 7u
#define G474_PWM_VL_PORT G474_PB /* TIM1_CH2N */
#define G474_PWM_VL_PIN 0u
#define G474_PWM_WL_PORT G474_PB /* TIM1_CH3N */
#define G474_PWM_WL_PIN 1u
#define G474_PWM_AF 6u
/** Gate-driver input polarity: 0 active high (L6398 HIN, LIN), 1 active low. */
#define G474_PWM_HS_ACTIVE_LOW 0u
#define G474_PWM_LS_ACTIVE_LOW 0u
/** Dead time (ns) inserted by TIM1 on top of the driver's own (VERIFY against
 *  the MOSFETs' switching times; the L6398 adds its fixed internal one). */
#define G474_DEAD_TIME_NS 800u

/* ---- hardware overcurrent: TIM1_BKIN (AF6), the stage's comparator ---- */
#define G474_BKIN_PORT G474_PA
#define G474_BKIN_PIN 6u
#define G474_BKIN_AF 6u
/** 1: the fault output pulls low on a trip (IHM08M1: VERIFY on the schematic). */
#define G474_BKIN_ACTIVE_LOW 1u

/* ---- ADC: ADC1 and ADC2, one injected sequence each, both triggered by
 *      TIM1 TRGO2 (RM0440 "Injected channel management"): rank 1 of both at once, then rank 2 ----
 */
#define G474_ADC_IA_PORT G474_PA /* phase U current */
#define G474_ADC_IA_PIN 0u
#define G474_ADC_IA_CH 1u        /* ADC1_IN1 */
#define G474_ADC_IC_PORT G474_PC /* phase W current */
#define G474_ADC_IC_PIN 0u
#define G474_ADC_IC_CH 6u        /* ADC1_IN6 */
#define G474_ADC_IB_PORT G474_PC /* phase V current */
#define G474_ADC_IB_PIN 1u
#define G474_ADC_IB_CH 7u         /* ADC2_IN7 */
#define G474_ADC_UDC_PORT G474_PA /* bus voltage divider */
#define G474_ADC_UDC_PIN 1u
#define G474_ADC_UDC_CH 2u /* ADC2_IN2 */
/** Low-side shunts into a non-inverting amplifier with a mid-scale offset
 *  read lower for a current into the motor (the SDK's "offset - reading"):
 *  1 mirrors the three current counts (max - raw) so that a larger count is
 *  more current into the motor, as the core expects. VERIFY with a DC test
 *  current (docs/hardware_bringup.md, step 4). */
#define G474_CURRENT_INVERT 1u
/** Shunt resistance (ohm) and amplifier gain: A per count =
 *  3.3 V / 4096 / (R_shunt * gain) = 0.01555 A/count, +-31.9 A full scale.
 *  VERIFY the gain (ST documents 5.18 for the IHM08M1's three-shunt network). */
#define G474_SHUNT_OHM 0.010f
#define G474_AMP_GAIN 5.18f
/** Bus-voltage divider ratio (V_bus / V_adc): 0.01547 V/count, 63.4 V full
 *  scale. VERIFY with a multimeter (hardware_bringup.md, step 3). */
#define G474_UDC_DIVIDER 19.2f
/** ADC reference (V): VREF+ tied to VDDA = 3.3 V on the NUCLEO. */
#define G474_VREF_V 3.3f
/** Hardware oversampling of the injected conversions: 1 (off) or 4 (x4,
 *  shifted right by one: 13-bit results). Off by default: README.md,
 *  "ADC oversampling", has the measurement and the time it costs. */
#define G474_ADC_OVERSAMPLE 1u

/** Power-stage limits applied over the drive's defaults at boot (the object
 *  dictionary 0x2050 changes them; 'save' keeps them). The IHM08M1 is a
 *  10..48 V stage: the core's 150..420 V defaults would trip at once. */
#define G474_U_DC_MIN_V 8.0f
#define G474_U_DC_MAX_V 52.0f
#define G474_I_TRIP_A 10.0f
#define G474_I_MAX_A 6.0f
#define G474_U_INJ_V 8.0f      /**< injection amplitude fitting a 24 V link */
#define G474_POL_PULSE_V 10.0f /**< polarity pulse voltage */

/* ---- CAN: FDCAN1 in classic mode on PB8 (RX) / PB9 (TX), AF9, to an
 *      external 3.3 V transceiver (the NUCLEO has none) ---- */
#define G474_CAN_RX_PORT G474_PB /* Arduino D15 */
#define G474_CAN_RX_PIN 8u
#define G474_CAN_TX_PORT G474_PB /* Arduino D14 */
#define G474_CAN_TX_PIN 9u
#define G474_CAN_AF 9u
/** 125000, 250000, 500000 or 1000000 (the EDS's BaudRate_* entries). */
#ifndef G474_CAN_BITRATE
#define G474_CAN_BITRATE 1000000u
#endif
#ifndef G474_NODE_ID
#define G474_NODE_ID 1u
#endif

/* ---- serial link: LPUART1 on PA2/PA3 (AF12), the ST-LINK's virtual COM
 *      port (UM2505, "Virtual COM port") ---- */
#define G474_UART_TX_PORT G474_PA
#define G474_UART_TX_PIN 2u
#define G474_UART_RX_PORT G474_PA
#define G474_UART_RX_PIN 3u
#define G474_UART_AF 12u
#define G474_UART_BAUD 921600u

/* ---- reference scale: TIM2 (32-bit) in encoder mode x4 on the IHM08M1's
 *      J3 (A+ PA15 = TIM2_CH1, B+ PB3 = TIM2_CH2, Z+ PB10 = TIM2_CH3, AF1) ---- */
/** 1: a quadrature scale is wired; 0: the board reports FW_REF_NONE. */
#ifndef G474_REF_SCALE
#define G474_REF_SCALE 1u
#endif
#define G474_ENC_A_PORT G474_PA
#define G474_ENC_A_PIN 15u
#define G474_ENC_B_PORT G474_PB
#define G474_ENC_B_PIN 3u
#define G474_ENC_AF 1u
/** 1: the reference mark (Z) is wired to TIM2_CH3: FW_REF_NOT_REFERENCED until
 *  it is first seen, counts from it afterwards. 0: counts from power-up. */
#ifndef G474_REF_INDEX
#define G474_REF_INDEX 1u
#endif
#define G474_ENC_Z_PORT G474_PB
#define G474_ENC_Z_PIN 10u
/** 1: the direction of positive travel counts down (swap instead of rewiring). */
#define G474_ENC_INVERT 0u
/** Scale error output (an alarm line): port, pin and active level; port
 *  G474_NO_PIN when not wired. */
#define G474_NO_PIN 0xFFu
#define G474_REF_FAULT_PORT G474_NO_PIN
#define G474_REF_FAULT_PIN 0u
#define G474_REF_FAULT_ACTIVE_LOW 1u

#endif /* G474_POWER_STAGE_CUSTOM */
#endif /* PMLSM_G474_PINMAP_H */
