#include "servo_pwm.h"

#include <avr/interrupt.h>
#include <avr/io.h>
#include <util/atomic.h>

#include "tumble_config.h"

namespace {

constexpr uint16_t kTicksPerUs = 2;  // 16 MHz / 8
constexpr uint8_t kClockBits = _BV(CS12) | _BV(CS11) | _BV(CS10);

// The compare value for a pulse of `us` microseconds. In fast PWM a pin is high from BOTTOM
// through the compare match, OCR1x + 1 ticks (as ICR1 + 1 ticks make the period): without
// the - 1 every pulse was one tick (half a microsecond) too long: 1500.5 us for 1500.
uint16_t compareTicks(uint16_t us) { return static_cast<uint16_t>(us * kTicksPerUs - 1); }

volatile uint16_t pendingA = 0, pendingB = 0;
volatile bool pending = false;
uint16_t appliedA = 0, appliedB = 0;  // last values handed to the ISR

}  // namespace

namespace servo_pwm {

void begin(uint16_t rightUs, uint16_t leftUs) {
  DDRB |= _BV(DDB1) | _BV(DDB2);  // D9, D10 outputs
  // TOP and compare values before the clock starts (simavr derives the period when
  // TCCR1B is written, and a zero TOP there would run the timer at 8 cycles).
  ICR1 = static_cast<uint16_t>(tumble::kServoPeriodUs * kTicksPerUs - 1);
  appliedA = compareTicks(rightUs);
  appliedB = compareTicks(leftUs);
  OCR1A = appliedA;
  OCR1B = appliedB;
  TCCR1A = _BV(COM1A1) | _BV(COM1B1) | _BV(WGM11);  // non-inverting PWM on OC1A, OC1B
  TCCR1B = _BV(WGM13) | _BV(WGM12) | _BV(CS11);     // mode 14 (TOP = ICR1), clk/8
  TIMSK1 |= _BV(TOIE1);
}

void write(uint16_t rightUs, uint16_t leftUs) {
  const uint16_t a = compareTicks(rightUs);
  const uint16_t b = compareTicks(leftUs);
  if (a == appliedA && b == appliedB) return;
  appliedA = a;
  appliedB = b;
  ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
    pendingA = a;
    pendingB = b;
    pending = true;
  }
}

}  // namespace servo_pwm

// At TOP: the next frame starts now, both outputs go high. New widths apply from here.
ISR(TIMER1_OVF_vect) {
  if (!pending) return;
  OCR1A = pendingA;
  OCR1B = pendingB;
  pending = false;
  // Stop and restart the timer clock (one CPU cycle; TCNT1 and the outputs hold). On the
  // part this is a no-op to within 0.5 us; simavr 1.6 only re-reads OCR1x when the clock
  // select changes, so without it the emulated pulses would never change.
  const uint8_t running = TCCR1B;
  TCCR1B = static_cast<uint8_t>(running & ~kClockBits);
  TCCR1B = running;
}
