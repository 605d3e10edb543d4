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
  if (!isForFirmware(frame.type)) {  // firmware -> agent types (an echo): counted, never answered
    refuse(Error::UnknownType, frame.seq, false);
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
      sendInfo();
      return;
    }
    case MsgType::GetStatus:
      sendStatus(nowMs);
      return;
    case MsgType::GetInfo:
      sendInfo();
      return;
    default:
      return;  // unreachable: decodeBody refuses unknown types
  }
}

void Controller::sendStatus(uint32_t nowMs) {
  StatusPayload status;
  status.uptimeMs = nowMs;
  status.right = speed(kRight);
  status.left = speed(kLeft);
  status.flags = static_cast<uint8_t>((armed_ ? 1 : 0) | (watchdogHolding() ? 2 : 0));
  status.framesOk = counters_.framesOk;
  status.crcErrors = counters_.crcErrors;
  status.otherDrops = counters_.otherDrops;
  status.watchdogTrips = counters_.watchdogTrips;
  status.lastSeq = lastSeq_;
  uint8_t p[StatusPayload::kSize];
  status.pack(p);
  send(MsgType::Status, p, sizeof p);
}

void Controller::sendInfo() {
  InfoPayload info;
  for (uint8_t s = 0; s < 2; ++s) {
    info.neutralUs[s] = trim_.neutralUs[s];
    info.direction[s] = trim_.direction[s];
  }
  uint8_t p[InfoPayload::kSize];
  info.pack(p);
  send(MsgType::Info, p, sizeof p);
}

void Controller::send(MsgType type, const uint8_t* payload, uint8_t len) {
  Frame frame;
  frame.epoch = epoch_;
  frame.seq = txSeq_++;
  frame.type = static_cast<uint8_t>(type);
  frame.len = len;
  for (uint8_t i = 0; i < len; ++i) frame.payload[i] = payload[i];
  uint8_t wire[kMaxWire + 1];
  wire[0] = 0x00;  // a leading delimiter ends any partial frame the agent holds after noise
  const size_t n = encodeFrame(frame, wire + 1);
  if (n == 0) return;  // unreachable: every payload the firmware sends fits
  port_.write(wire, n + 1);
}

}  // namespace tumble
