// Tunables of the tumblebot firmware, with units. One place for every number.
#pragma once
#include <stdint.h>

namespace tumble {

constexpr uint8_t kProtocolVersion = 1;
constexpr uint8_t kFirmwareMajor = 1;
constexpr uint8_t kFirmwareMinor = 1;
constexpr uint8_t kFirmwarePatch = 0;

constexpr uint32_t kBaudRate = 115200;          // serial link, 8N1

constexpr uint16_t kLinkTimeoutMs = 250;        // no valid SET_SPEEDS for this long: both servos neutral
                                                // (applied at the next 20 ms frame: neutral within 300 ms)
constexpr uint16_t kReadyIntervalMs = 500;      // READY is repeated this often until the first valid frame

constexpr uint16_t kNeutralUs = 1500;           // default servo neutral pulse, microseconds
constexpr uint16_t kFullSpeedDeltaUs = 500;     // full speed = neutral +- this (1000 / 2000 us)
constexpr uint16_t kNeutralMinUs = 1300;        // accepted range of a neutral trim, microseconds
constexpr uint16_t kNeutralMaxUs = 1700;
constexpr uint16_t kServoPeriodUs = 20000;      // 50 Hz servo frame

// Wire sizes (see docs/protocol.md).
constexpr uint8_t kHeaderSize = 6;              // version u8, epoch u16, seq u16, type u8
constexpr uint8_t kCrcSize = 2;
constexpr uint8_t kMaxPayload = 20;
constexpr uint8_t kMaxBody = kHeaderSize + kMaxPayload + kCrcSize;   // 28
constexpr uint8_t kMaxEncoded = kMaxBody + 1;                         // COBS overhead, no delimiter
constexpr uint8_t kMaxWire = kMaxEncoded + 1;                         // with the 0x00 delimiter

}  // namespace tumble
