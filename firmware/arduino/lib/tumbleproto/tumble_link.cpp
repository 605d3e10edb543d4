#include "tumble_link.h"

namespace tumble {

bool Trim::valid() const {
  for (uint8_t s = 0; s < 2; ++s) {
    if (neutralUs[s] < kNeutralMinUs || neutralUs[s] > kNeutralMaxUs) return false;
    if (direction[s] != 1 && direction[s] != -1) return false;
  }
  return true;
}

void Controller::begin(uint32_t nowMs) {
  uint8_t payload[4] = {kProtocolVersion, kFirmwareMajor, kFirmwareMinor, kFirmwarePatch};
  send(MsgType::Ready, payload, sizeof payload);
  lastReadyMs_ = nowMs;
}

void Controller::onByte(uint8_t byte, uint32_t nowMs) {
  Frame frame;
  switch (reader_.feed(byte, frame)) {
    case FrameReader::Result::None:
      return;
    case FrameReader::Result::Error:
      refuse(reader_.error(), 0, false);  // nothing in it can be trusted, not even its seq
      return;
    case FrameReader::Result::Frame:
      handle(frame, nowMs);
      return;
  }
}

void Controller::tick(uint32_t nowMs) {
  if (armed_ && !timedOut_ && nowMs - lastCommandMs_ >= kLinkTimeoutMs) {
    timedOut_ = true;
    ++counters_.watchdogTrips;
  }
  if (!heardFromAgent_ && nowMs - lastReadyMs_ >= kReadyIntervalMs) begin(nowMs);
}

uint16_t Controller::pulseUs(uint8_t servo) const {
  const int16_t delta = static_cast<int16_t>(speed(servo) * trim_.direction[servo] * static_cast<int16_t>(kFullSpeedDeltaUs));
  return static_cast<uint16_t>(static_cast<int16_t>(trim_.neutralUs[servo]) + delta);
}

void Controller::refuse(Error error, uint16_t seq, bool reply) {
  if (error == Error::BadCrc) {
    ++counters_.crcErrors;
  } else {
    ++counters_.otherDrops;
  }
  ++counters_.byError[static_cast<uint8_t>(error)];
  if (reply) {
    uint8_t payload[3] = {static_cast<uint8_t>(error), 0, 0};
    putU16(payload + 1, seq);
    send(MsgType::Error, payload, sizeof payload);
  }
}

void Controller::handle(const Frame& frame, uint32_t nowMs) {
  const auto type = static_cast<MsgType>(frame.type);
  if (static_cast<uint8_t>(frame.type) >= 0x80) {  // firmware -> agent types are not for us
    refuse(Error::UnknownType, frame.seq, true);
    return;
  }
  if (frame.epoch != epoch_) {
    refuse(Error::StaleEpoch, frame.seq, true);
    return;
  }
  if (haveSeq_ && !newer(frame.seq, lastSeq_)) {
    refuse(Error::OldSequence, frame.seq, true);
    return;
  }
  haveSeq_ = true;
  lastSeq_ = frame.seq;
  heardFromAgent_ = true;
  ++counters_.framesOk;
  switch (type) {
    case MsgType::SetSpeeds:
      speed_[kRight] = static_cast<int8_t>(frame.payload[0]);
      speed_[kLeft] = static_cast<int8_t>(frame.payload[1]);
      armed_ = true;
      timedOut_ = false;
      lastCommandMs_ = nowMs;
      return;
    case MsgType::Ping:
      send(MsgType::Pong, frame.payload, 4);
      return;
    case MsgType::SetTrim: {
      const uint8_t servo = frame.payload[0];
      trim_.neutralUs[servo] = getU16(frame.payload + 1);
      trim_.direction[servo] = static_cast<int8_t>(frame.payload[3]);
      port_.saveTrim(trim_);
      sendStatus(nowMs);
      return;
    }
    case MsgType::GetStatus:
      sendStatus(nowMs);
      return;
    default:
      return;  // unreachable: decodeBody refuses unknown types
  }
}

void Controller::sendStatus(uint32_t nowMs) {
  uint8_t p[17];
  putU32(p, nowMs);
  p[4] = static_cast<uint8_t>(speed(kRight));
  p[5] = static_cast<uint8_t>(speed(kLeft));
  p[6] = static_cast<uint8_t>((armed_ ? 1 : 0) | (watchdogHolding() ? 2 : 0));
  putU16(p + 7, counters_.framesOk);
  putU16(p + 9, counters_.crcErrors);
  putU16(p + 11, counters_.otherDrops);
  putU16(p + 13, counters_.watchdogTrips);
  putU16(p + 15, lastSeq_);
  send(MsgType::Status, p, sizeof p);
}

void Controller::send(MsgType type, const uint8_t* payload, uint8_t len) {
  Frame frame;
  frame.epoch = epoch_;
  frame.seq = txSeq_++;
  frame.type = static_cast<uint8_t>(type);
  frame.len = len;
  for (uint8_t i = 0; i < len; ++i) frame.payload[i] = payload[i];
  uint8_t wire[kMaxWire];
  const size_t n = encodeFrame(frame, wire);
  port_.write(wire, n);
}

}  // namespace tumble
