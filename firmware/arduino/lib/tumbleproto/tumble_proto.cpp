#include "tumble_proto.h"

#include <string.h>

namespace tumble {

const char* toString(Error e) {
  switch (e) {
    case Error::Ok: return "OK";
    case Error::BadCrc: return "BAD_CRC";
    case Error::BadCobs: return "BAD_COBS";
    case Error::TooLong: return "TOO_LONG";
    case Error::TooShort: return "TOO_SHORT";
    case Error::BadVersion: return "BAD_VERSION";
    case Error::StaleEpoch: return "STALE_EPOCH";
    case Error::OldSequence: return "OLD_SEQUENCE";
    case Error::UnknownType: return "UNKNOWN_TYPE";
    case Error::BadPayload: return "BAD_PAYLOAD";
  }
  return "UNKNOWN_ERROR";
}

uint16_t crc16_mcrf4xx(const uint8_t* data, size_t len, uint16_t crc) {
  for (size_t i = 0; i < len; ++i) {
    crc ^= data[i];
    for (uint8_t bit = 0; bit < 8; ++bit) {
      crc = (crc & 1u) ? static_cast<uint16_t>((crc >> 1) ^ 0x8408u) : static_cast<uint16_t>(crc >> 1);
    }
  }
  return crc;
}

size_t cobsEncode(const uint8_t* in, size_t len, uint8_t* out) {
  size_t codeAt = 0, o = 1;
  uint8_t code = 1;
  for (size_t i = 0; i < len; ++i) {
    if (in[i] == 0) {
      out[codeAt] = code;
      codeAt = o++;
      code = 1;
    } else {
      out[o++] = in[i];
      if (++code == 0xFF) {
        out[codeAt] = code;
        codeAt = o++;
        code = 1;
      }
    }
  }
  out[codeAt] = code;
  return o;
}

bool cobsDecode(const uint8_t* in, size_t len, uint8_t* out, size_t* outLen) {
  size_t i = 0, o = 0;
  while (i < len) {
    const uint8_t code = in[i];
    const size_t end = i + code;
    if (code == 0 || end > len) return false;
    for (size_t k = i + 1; k < end; ++k) {
      if (in[k] == 0) return false;
      out[o++] = in[k];
    }
    i = end;
    if (code != 0xFF && i < len) out[o++] = 0;
  }
  *outLen = o;
  return true;
}

int payloadSize(uint8_t type) {
  switch (static_cast<MsgType>(type)) {
    case MsgType::SetSpeeds: return 2;
    case MsgType::Ping: return 4;
    case MsgType::SetTrim: return 4;
    case MsgType::GetStatus: return 0;
    case MsgType::GetInfo: return 0;
    case MsgType::Ready: return 4;
    case MsgType::Pong: return 4;
    case MsgType::Status: return StatusPayload::kSize;
    case MsgType::Info: return InfoPayload::kSize;
    case MsgType::Error: return 3;
  }
  return -1;
}

void StatusPayload::pack(uint8_t* p) const {
  putU32(p, uptimeMs);
  p[4] = static_cast<uint8_t>(right);
  p[5] = static_cast<uint8_t>(left);
  p[6] = flags;
  putU16(p + 7, framesOk);
  putU16(p + 9, crcErrors);
  putU16(p + 11, otherDrops);
  putU16(p + 13, watchdogTrips);
  putU16(p + 15, lastSeq);
}

void InfoPayload::pack(uint8_t* p) const {
  p[0] = protocol;
  p[1] = major;
  p[2] = minor;
  p[3] = patch;
  putU16(p + 4, neutralUs[0]);
  p[6] = static_cast<uint8_t>(direction[0]);
  putU16(p + 7, neutralUs[1]);
  p[9] = static_cast<uint8_t>(direction[1]);
}

size_t encodeFrame(const Frame& frame, uint8_t* out) {
  if (frame.len > kMaxPayload) return 0;
  uint8_t body[kMaxBody];
  body[0] = kProtocolVersion;
  putU16(body + 1, frame.epoch);
  putU16(body + 3, frame.seq);
  body[5] = frame.type;
  memcpy(body + kHeaderSize, frame.payload, frame.len);
  const size_t n = kHeaderSize + frame.len;
  putU16(body + n, crc16_mcrf4xx(body, n));
  const size_t encoded = cobsEncode(body, n + kCrcSize, out);
  out[encoded] = 0;
  return encoded + 1;
}

static bool isSpeed(uint8_t raw) {
  const int8_t v = static_cast<int8_t>(raw);
  return v >= -1 && v <= 1;
}

Error decodeBody(const uint8_t* encoded, size_t len, Frame& out) {
  if (len > kMaxEncoded) return Error::TooLong;
  uint8_t body[kMaxEncoded];
  size_t n = 0;
  if (!cobsDecode(encoded, len, body, &n)) return Error::BadCobs;
  if (n < kHeaderSize + kCrcSize) return Error::TooShort;
  if (n > kMaxBody) return Error::TooLong;
  if (crc16_mcrf4xx(body, n - kCrcSize) != getU16(body + n - kCrcSize)) return Error::BadCrc;
  if (body[0] != kProtocolVersion) return Error::BadVersion;
  const int expected = payloadSize(body[5]);
  if (expected < 0) return Error::UnknownType;
  const size_t plen = n - kHeaderSize - kCrcSize;
  if (plen != static_cast<size_t>(expected)) return Error::BadPayload;
  const uint8_t* p = body + kHeaderSize;
  const auto type = static_cast<MsgType>(body[5]);
  if (type == MsgType::SetSpeeds && !(isSpeed(p[0]) && isSpeed(p[1]))) return Error::BadPayload;
  if (type == MsgType::SetTrim) {
    const uint16_t neutral = getU16(p + 1);
    const int8_t direction = static_cast<int8_t>(p[3]);
    if (p[0] > 1 || neutral < kNeutralMinUs || neutral > kNeutralMaxUs || (direction != 1 && direction != -1)) {
      return Error::BadPayload;
    }
  }
  out.epoch = getU16(body + 1);
  out.seq = getU16(body + 3);
  out.type = body[5];
  out.len = static_cast<uint8_t>(plen);
  memcpy(out.payload, p, plen);
  return Error::Ok;
}

FrameReader::Result FrameReader::feed(uint8_t byte, Frame& out) {
  if (byte != 0) {
    if (len_ < kMaxEncoded) {
      buffer_[len_++] = byte;
    } else {
      overflow_ = true;
    }
    return Result::None;
  }
  Result result = Result::None;
  if (overflow_) {
    error_ = Error::TooLong;
    result = Result::Error;
  } else if (len_ > 0) {
    error_ = decodeBody(buffer_, len_, out);
    result = error_ == Error::Ok ? Result::Frame : Result::Error;
  }
  len_ = 0;
  overflow_ = false;
  return result;
}

}  // namespace tumble
