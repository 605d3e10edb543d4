// tumblebot serial protocol, C++ side: CRC-16/MCRF4XX, COBS framing, frame encode and
// decode. Plain C++ (no Arduino.h, no heap, no exceptions): host-tested with doctest and
// built for the ATmega328P. The byte tables are in docs/protocol.md; both this library
// and the Python twin (firmware/pi_agent/protocol.py) check firmware/protocol/vectors.txt.
#pragma once
#include <stddef.h>
#include <stdint.h>

#include "tumble_config.h"

namespace tumble {

enum class MsgType : uint8_t {
  SetSpeeds = 0x01,  // right i8, left i8 in {-1, 0, +1}
  Ping = 0x02,       // token u32
  SetTrim = 0x03,    // servo u8 (0 right, 1 left), neutral_us u16, direction i8 (+-1)
  GetStatus = 0x04,  // no payload
  GetInfo = 0x05,    // no payload; answered with INFO
  Ready = 0x80,      // protocol u8, firmware major u8, minor u8, patch u8
  Pong = 0x81,       // token u32
  Status = 0x82,     // 17 bytes, see StatusPayload
  Info = 0x83,       // 10 bytes, see InfoPayload: versions and the trims in force
  Error = 0x8F,      // code u8, offending seq u16
};

// Why a frame was refused. Values are on the wire (ERROR payload) and match the Python enum.
enum class Error : uint8_t {
  Ok = 0,
  BadCrc = 1,
  BadCobs = 2,
  TooLong = 3,
  TooShort = 4,
  BadVersion = 5,
  StaleEpoch = 6,
  OldSequence = 7,
  UnknownType = 8,
  BadPayload = 9,
};
constexpr uint8_t kErrorCount = 10;

const char* toString(Error e);

uint16_t crc16_mcrf4xx(const uint8_t* data, size_t len, uint16_t crc = 0xFFFF);

// COBS-encode len bytes into out (capacity >= len + len / 254 + 1); returns bytes written.
size_t cobsEncode(const uint8_t* in, size_t len, uint8_t* out);
// Decode; returns false on a malformed block. out needs capacity >= len.
bool cobsDecode(const uint8_t* in, size_t len, uint8_t* out, size_t* outLen);

struct Frame {
  uint16_t epoch = 0;
  uint16_t seq = 0;
  uint8_t type = 0;
  uint8_t len = 0;  // payload length
  uint8_t payload[kMaxPayload] = {};
};

// The message table (docs/protocol.md, "Messages"; Python: protocol.MESSAGES).
// Exact payload size of a message type, or -1 for an unknown type.
int payloadSize(uint8_t type);
// Agent -> firmware types are below 0x80; firmware -> agent types from 0x80.
inline bool isForFirmware(uint8_t type) { return type < 0x80; }

// STATUS payload (17 bytes, little-endian), packed in one place.
struct StatusPayload {
  uint32_t uptimeMs = 0;
  int8_t right = 0;
  int8_t left = 0;
  uint8_t flags = 0;  // bit 0 armed, bit 1 watchdog holding neutral
  uint16_t framesOk = 0;
  uint16_t crcErrors = 0;
  uint16_t otherDrops = 0;
  uint16_t watchdogTrips = 0;
  uint16_t lastSeq = 0;
  static constexpr uint8_t kSize = 17;
  void pack(uint8_t* out) const;  // out: kSize bytes
};

// INFO payload (10 bytes, little-endian): what the firmware is and the trims it holds.
struct InfoPayload {
  uint8_t protocol = kProtocolVersion;
  uint8_t major = kFirmwareMajor;
  uint8_t minor = kFirmwareMinor;
  uint8_t patch = kFirmwarePatch;
  uint16_t neutralUs[2] = {kNeutralUs, kNeutralUs};  // right, left
  int8_t direction[2] = {1, -1};
  static constexpr uint8_t kSize = 10;
  void pack(uint8_t* out) const;  // out: kSize bytes: protocol, major, minor, patch, right neutral u16,
                                  // right direction i8, left neutral u16, left direction i8
};

// Frame -> wire bytes including the trailing 0x00 (out capacity >= kMaxWire). 0 if too long.
size_t encodeFrame(const Frame& frame, uint8_t* out);

// One frame's bytes without the delimiter -> frame. Checks length, COBS, CRC, version,
// type, payload size and value ranges. Epoch and sequence policy is the receiver's.
Error decodeBody(const uint8_t* encoded, size_t len, Frame& out);

// Byte stream -> frames. Overlong frames are dropped up to the next delimiter.
class FrameReader {
 public:
  enum class Result : uint8_t { None, Frame, Error };
  // Feed one byte. On Result::Frame, `out` holds the frame; on Result::Error, error().
  Result feed(uint8_t byte, Frame& out);
  Error error() const { return error_; }

 private:
  uint8_t buffer_[kMaxEncoded] = {};
  uint8_t len_ = 0;
  bool overflow_ = false;
  Error error_ = Error::Ok;
};

// 16-bit serial-number arithmetic: does seq come after last?
inline bool newer(uint16_t seq, uint16_t last) {
  const uint16_t delta = static_cast<uint16_t>(seq - last);
  return delta != 0 && delta < 0x8000u;
}

// Little-endian helpers.
inline void putU16(uint8_t* p, uint16_t v) { p[0] = static_cast<uint8_t>(v & 0xFF); p[1] = static_cast<uint8_t>(v >> 8); }
inline void putU32(uint8_t* p, uint32_t v) { for (int i = 0; i < 4; ++i) p[i] = static_cast<uint8_t>((v >> (8 * i)) & 0xFF); }
inline uint16_t getU16(const uint8_t* p) { return static_cast<uint16_t>(p[0] | (p[1] << 8)); }
inline uint32_t getU32(const uint8_t* p) {
  return static_cast<uint32_t>(p[0]) | (static_cast<uint32_t>(p[1]) << 8) |
         (static_cast<uint32_t>(p[2]) << 16) | (static_cast<uint32_t>(p[3]) << 24);
}

}  // namespace tumble
