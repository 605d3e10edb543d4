// The firmware's logic, free of hardware: frame handling, arming, the link watchdog and
// the servo pulse widths. src/main.cpp feeds it bytes and the time, and writes what
// pulseUs() says to Timer1; the host tests drive it directly.
#pragma once
#include <stddef.h>
#include <stdint.h>

#include "tumble_proto.h"

namespace tumble {

constexpr uint8_t kRight = 0;
constexpr uint8_t kLeft = 1;

// Per-servo neutral pulse and direction (+1, or -1 for the mirrored servo). Stored in EEPROM.
struct Trim {
  uint16_t neutralUs[2] = {kNeutralUs, kNeutralUs};
  int8_t direction[2] = {1, -1};  // the left servo is mounted mirrored
  bool valid() const;
};

// What the logic needs from the outside world.
class Port {
 public:
  virtual void write(const uint8_t* data, size_t len) = 0;  // bytes onto the serial line
  virtual void saveTrim(const Trim& trim) = 0;               // persist (EEPROM on the Uno)

 protected:
  ~Port() = default;  // never deleted through a Port pointer (no heap on the Uno)
};

struct Counters {
  uint16_t framesOk = 0;       // frames accepted
  uint16_t crcErrors = 0;      // frames with a bad CRC
  uint16_t otherDrops = 0;     // every other refused frame (COBS, length, version, epoch, seq, type, payload)
  uint16_t watchdogTrips = 0;  // times the link watchdog forced neutral
  uint16_t byError[kErrorCount] = {};
};

class Controller {
 public:
  Controller(uint16_t epoch, const Trim& trim, Port& port) : epoch_(epoch), trim_(trim), port_(port) {}

  void begin(uint32_t nowMs);                 // send READY
  void onByte(uint8_t byte, uint32_t nowMs);  // one received byte
  void tick(uint32_t nowMs);                  // watchdog and READY repetition; call often

  uint16_t pulseUs(uint8_t servo) const;      // the pulse this servo must get now, microseconds
  int8_t speed(uint8_t servo) const { return active() ? speed_[servo] : 0; }
  bool armed() const { return armed_; }
  bool watchdogHolding() const { return armed_ && timedOut_; }
  const Counters& counters() const { return counters_; }
  const Trim& trim() const { return trim_; }
  uint16_t epoch() const { return epoch_; }

 private:
  bool active() const { return armed_ && !timedOut_; }
  void handle(const Frame& frame, uint32_t nowMs);
  void refuse(Error error, uint16_t seq, bool reply);
  void send(MsgType type, const uint8_t* payload, uint8_t len);
  void sendStatus(uint32_t nowMs);
  void sendInfo();

  uint16_t epoch_;
  Trim trim_;
  Port& port_;
  FrameReader reader_;
  Counters counters_;
  int8_t speed_[2] = {0, 0};
  bool armed_ = false;          // a valid SET_SPEEDS since boot
  bool timedOut_ = false;       // watchdog holding neutral
  bool heardFromAgent_ = false; // a valid frame since boot: stop repeating READY
  bool haveSeq_ = false;
  uint16_t lastSeq_ = 0;
  uint16_t txSeq_ = 0;
  uint32_t lastCommandMs_ = 0;
  uint32_t lastReadyMs_ = 0;
};

}  // namespace tumble
