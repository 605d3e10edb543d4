// tumblebot motor firmware for the Arduino Uno (ATmega328P, 16 MHz): glue between the
// hardware and the pure logic in lib/tumbleproto. Serial in, servo pulses out, EEPROM for
// trims and the boot epoch, the AVR watchdog for a hung loop.
#include <Arduino.h>
#include <avr/eeprom.h>
#include <avr/wdt.h>

#include "servo_pwm.h"
#include "tumble_link.h"

namespace {

// EEPROM layout: magic, boot counter (the epoch), trims.
struct Stored {
  uint16_t magic;
  uint16_t bootCount;
  tumble::Trim trim;
};
constexpr uint16_t kMagic = 0x7B01;
Stored* const kEeprom = reinterpret_cast<Stored*>(0);

class UnoPort : public tumble::Port {
 public:
  void write(const uint8_t* data, size_t len) override { Serial.write(data, len); }
  void saveTrim(const tumble::Trim& trim) override {
    eeprom_update_block(&trim, &kEeprom->trim, sizeof trim);
  }
};

UnoPort port;
tumble::Controller* controller = nullptr;

// Built once, in setup(), when the epoch and trims have been read from EEPROM.
tumble::Controller& makeController(uint16_t epoch, const tumble::Trim& trim) {
  static tumble::Controller instance(epoch, trim, port);
  return instance;
}

}  // namespace

// Clear a watchdog reset before anything else runs, or the watchdog stays armed at its
// shortest period and the board resets forever.
extern "C" void disableWatchdogEarly() __attribute__((naked, used, section(".init3")));
extern "C" void disableWatchdogEarly() {
  MCUSR = 0;
  wdt_disable();
}

void setup() {
  servo_pwm::begin(tumble::kNeutralUs, tumble::kNeutralUs);  // neutral before anything else
  Stored stored;
  eeprom_read_block(&stored, kEeprom, sizeof stored);
  if (stored.magic != kMagic || !stored.trim.valid()) {
    stored.magic = kMagic;
    stored.bootCount = 0;
    stored.trim = tumble::Trim{};
  }
  stored.bootCount = static_cast<uint16_t>(stored.bootCount + 1);
  eeprom_update_block(&stored, kEeprom, sizeof stored);

  controller = &makeController(stored.bootCount, stored.trim);
  servo_pwm::write(controller->pulseUs(tumble::kRight), controller->pulseUs(tumble::kLeft));
  Serial.begin(tumble::kBaudRate);
  controller->begin(millis());
  wdt_enable(WDTO_250MS);
}

void loop() {
  wdt_reset();
  while (Serial.available() > 0) {
    controller->onByte(static_cast<uint8_t>(Serial.read()), millis());
  }
  controller->tick(millis());
  servo_pwm::write(controller->pulseUs(tumble::kRight), controller->pulseUs(tumble::kLeft));
}
