// Servo pulses from Timer1 hardware PWM on D9 (OC1A, right servo) and D10 (OC1B, left
// servo): fast PWM mode 14, TOP = ICR1, prescaler 8 -> 0.5 us per tick at 16 MHz,
// 20 ms (50 Hz) frames. The only code that touches the timer.
#pragma once
#include <avr/io.h>
#include <stdint.h>

#include "tumble_config.h"

namespace servo_pwm {

constexpr uint16_t kTicksPerUs = 2;  // 16 MHz / 8

inline void begin(uint16_t rightUs, uint16_t leftUs) {
  DDRB |= _BV(DDB1) | _BV(DDB2);  // D9, D10 outputs
  TCCR1A = _BV(COM1A1) | _BV(COM1B1) | _BV(WGM11);
  TCCR1B = _BV(WGM13) | _BV(WGM12) | _BV(CS11);
  ICR1 = static_cast<uint16_t>(tumble::kServoPeriodUs * kTicksPerUs - 1);
  OCR1A = static_cast<uint16_t>(rightUs * kTicksPerUs);
  OCR1B = static_cast<uint16_t>(leftUs * kTicksPerUs);
}

// Double-buffered by the hardware: a new width takes effect at the next 20 ms frame.
inline void write(uint16_t rightUs, uint16_t leftUs) {
  OCR1A = static_cast<uint16_t>(rightUs * kTicksPerUs);
  OCR1B = static_cast<uint16_t>(leftUs * kTicksPerUs);
}

}  // namespace servo_pwm
