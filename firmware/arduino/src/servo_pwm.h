// Servo pulses from Timer1 hardware PWM on D9 (OC1A, right servo) and D10 (OC1B, left
// servo): fast PWM mode 14, TOP = ICR1, prescaler 8 -> 0.5 us per tick at 16 MHz,
// 20 ms (50 Hz) frames. The only code that touches the timer.
#pragma once
#include <stdint.h>

namespace servo_pwm {

// Start the timer with both outputs at the given pulse widths (microseconds).
void begin(uint16_t rightUs, uint16_t leftUs);

// Ask for new pulse widths. They take effect at the start of the next 20 ms frame, from
// the Timer1 overflow interrupt, so no pulse is ever cut short or stretched.
void write(uint16_t rightUs, uint16_t leftUs);

}  // namespace servo_pwm
