// The firmware logic: arming, the link watchdog, epoch and sequence rules, replies, trims.
#include <doctest/doctest.h>

#include <random>
#include <vector>

#include "tumble_link.h"

using namespace tumble;

namespace {

struct FakePort : Port {
  std::vector<uint8_t> written;
  int trimSaves = 0;
  Trim saved;
  void write(const uint8_t* data, size_t len) override { written.insert(written.end(), data, data + len); }
  void saveTrim(const Trim& trim) override { saved = trim; ++trimSaves; }

  std::vector<Frame> frames() {
    std::vector<Frame> out;
    FrameReader reader;
    Frame f;
    for (uint8_t b : written) {
      if (reader.feed(b, f) == FrameReader::Result::Frame) out.push_back(f);
    }
    written.clear();
    return out;
  }
};

constexpr uint16_t kEpoch = 0x1234;

std::vector<uint8_t> wire(MsgType type, std::vector<uint8_t> payload, uint16_t seq, uint16_t epoch = kEpoch) {
  Frame f;
  f.epoch = epoch;
  f.seq = seq;
  f.type = static_cast<uint8_t>(type);
  f.len = static_cast<uint8_t>(payload.size());
  std::copy(payload.begin(), payload.end(), f.payload);
  uint8_t out[kMaxWire];
  const size_t n = encodeFrame(f, out);
  return {out, out + n};
}

std::vector<uint8_t> speeds(int8_t right, int8_t left, uint16_t seq, uint16_t epoch = kEpoch) {
  return wire(MsgType::SetSpeeds, {static_cast<uint8_t>(right), static_cast<uint8_t>(left)}, seq, epoch);
}

void feed(Controller& c, const std::vector<uint8_t>& bytes, uint32_t now) {
  for (uint8_t b : bytes) c.onByte(b, now);
}

}  // namespace

TEST_CASE("at boot the servos are neutral and READY carries versions and the epoch") {
  FakePort port;
  Controller c(kEpoch, Trim{}, port);
  c.begin(0);
  auto frames = port.frames();
  REQUIRE(frames.size() == 1);
  CHECK(frames[0].type == static_cast<uint8_t>(MsgType::Ready));
  CHECK(frames[0].epoch == kEpoch);
  CHECK(frames[0].payload[0] == kProtocolVersion);
  CHECK(c.pulseUs(kRight) == 1500);
  CHECK(c.pulseUs(kLeft) == 1500);
  CHECK_FALSE(c.armed());
}

TEST_CASE("READY repeats until the agent is heard") {
  FakePort port;
  Controller c(kEpoch, Trim{}, port);
  c.begin(0);
  c.tick(kReadyIntervalMs);
  c.tick(2 * kReadyIntervalMs);
  CHECK(port.frames().size() == 3);
  feed(c, speeds(0, 0, 1), 2 * kReadyIntervalMs + 1);
  c.tick(10 * kReadyIntervalMs);
  CHECK(port.frames().empty());
}

TEST_CASE("set speeds moves the servos, with the left one mirrored") {
  FakePort port;
  Controller c(kEpoch, Trim{}, port);
  feed(c, speeds(1, 1, 1), 10);
  CHECK(c.armed());
  CHECK(c.pulseUs(kRight) == 2000);
  CHECK(c.pulseUs(kLeft) == 1000);
  feed(c, speeds(-1, 0, 2), 20);
  CHECK(c.pulseUs(kRight) == 1000);
  CHECK(c.pulseUs(kLeft) == 1500);
}

TEST_CASE("the link watchdog forces neutral 300 ms after the last valid command, every time") {
  FakePort port;
  Controller c(kEpoch, Trim{}, port);
  uint16_t seq = 1;
  for (int round = 0; round < 3; ++round) {
    const uint32_t t0 = 1000u * static_cast<uint32_t>(round + 1);
    feed(c, speeds(1, -1, seq++), t0);
    c.tick(t0 + kLinkTimeoutMs - 1);
    CHECK(c.pulseUs(kRight) == 2000);
    c.tick(t0 + kLinkTimeoutMs);
    CHECK(c.pulseUs(kRight) == 1500);
    CHECK(c.pulseUs(kLeft) == 1500);
    CHECK(c.watchdogHolding());
  }
  CHECK(c.counters().watchdogTrips == 3);
}

TEST_CASE("the watchdog handles millis() wrapping around") {
  FakePort port;
  Controller c(kEpoch, Trim{}, port);
  const uint32_t t0 = 0xFFFFFF00u;
  feed(c, speeds(1, 1, 1), t0);
  c.tick(t0 + 200);  // wrapped
  CHECK(c.pulseUs(kRight) == 2000);
  c.tick(t0 + kLinkTimeoutMs);
  CHECK(c.pulseUs(kRight) == 1500);
}

TEST_CASE("replayed or old sequence numbers and stale epochs never move the robot") {
  FakePort port;
  Controller c(kEpoch, Trim{}, port);
  feed(c, speeds(0, 0, 10), 0);
  port.frames();
  feed(c, speeds(1, 1, 10), 1);  // replay of seq 10
  feed(c, speeds(1, 1, 9), 2);   // older
  feed(c, speeds(1, 1, 11, kEpoch + 1), 3);  // another boot's epoch
  CHECK(c.pulseUs(kRight) == 1500);
  auto replies = port.frames();
  REQUIRE(replies.size() == 3);
  CHECK(replies[0].payload[0] == static_cast<uint8_t>(Error::OldSequence));
  CHECK(replies[2].payload[0] == static_cast<uint8_t>(Error::StaleEpoch));
  CHECK(c.counters().otherDrops == 3);
  feed(c, speeds(1, 1, 11), 4);
  CHECK(c.pulseUs(kRight) == 2000);
}

TEST_CASE("sequence numbers wrap around 0xFFFF") {
  FakePort port;
  Controller c(kEpoch, Trim{}, port);
  feed(c, speeds(0, 0, 0xFFFF), 0);
  feed(c, speeds(1, 0, 0), 1);
  CHECK(c.pulseUs(kRight) == 2000);
}

TEST_CASE("ping is answered with the same token, status reports counters") {
  FakePort port;
  Controller c(kEpoch, Trim{}, port);
  feed(c, wire(MsgType::Ping, {1, 2, 3, 4}, 1), 5);
  feed(c, wire(MsgType::GetStatus, {}, 2), 6);
  auto replies = port.frames();
  REQUIRE(replies.size() == 2);
  CHECK(replies[0].type == static_cast<uint8_t>(MsgType::Pong));
  CHECK(getU32(replies[0].payload) == 0x04030201u);
  CHECK(replies[1].type == static_cast<uint8_t>(MsgType::Status));
  CHECK(getU32(replies[1].payload) == 6);
  CHECK(getU16(replies[1].payload + 7) == 2);  // frames ok
}

TEST_CASE("trims are applied, persisted and reported") {
  FakePort port;
  Controller c(kEpoch, Trim{}, port);
  feed(c, wire(MsgType::SetTrim, {0, 0xDC, 0x05, 0xFF}, 1), 0);  // right: 1500 -> 1500, direction -1
  feed(c, wire(MsgType::SetTrim, {1, 0xF0, 0x05, 0x01}, 2), 0);  // left: neutral 1520, direction +1
  CHECK(port.trimSaves == 2);
  CHECK(port.saved.neutralUs[kLeft] == 1520);
  auto replies = port.frames();  // each SET_TRIM is answered with INFO: the trims now in force
  REQUIRE(replies.size() == 2);
  CHECK(replies[1].type == static_cast<uint8_t>(MsgType::Info));
  CHECK(getU16(replies[1].payload + 4) == 1500);
  CHECK(static_cast<int8_t>(replies[1].payload[6]) == -1);
  CHECK(getU16(replies[1].payload + 7) == 1520);
  CHECK(static_cast<int8_t>(replies[1].payload[9]) == 1);
  feed(c, speeds(1, 1, 3), 1);
  CHECK(c.pulseUs(kRight) == 1000);
  CHECK(c.pulseUs(kLeft) == 2020);
}

TEST_CASE("GET_INFO tells the versions and the trims in force") {
  FakePort port;
  Controller c(kEpoch, Trim{}, port);
  feed(c, wire(MsgType::GetInfo, {}, 1), 0);
  auto replies = port.frames();
  REQUIRE(replies.size() == 1);
  CHECK(replies[0].type == static_cast<uint8_t>(MsgType::Info));
  CHECK(replies[0].payload[0] == kProtocolVersion);
  CHECK(replies[0].payload[1] == kFirmwareMajor);
  CHECK(replies[0].payload[2] == kFirmwareMinor);
  CHECK(replies[0].payload[3] == kFirmwarePatch);
  CHECK(getU16(replies[0].payload + 4) == 1500);
  CHECK(static_cast<int8_t>(replies[0].payload[6]) == 1);
  CHECK(getU16(replies[0].payload + 7) == 1500);
  CHECK(static_cast<int8_t>(replies[0].payload[9]) == -1);
  CHECK(c.speed(kRight) == 0);  // asking never arms
  CHECK_FALSE(c.armed());
}

TEST_CASE("random bytes never actuate and are all counted") {
  FakePort port;
  Controller c(kEpoch, Trim{}, port);
  std::mt19937 rng(1);
  for (int i = 0; i < 1000000; ++i) {
    c.onByte(static_cast<uint8_t>(rng()), static_cast<uint32_t>(i / 100));
    REQUIRE(c.pulseUs(kRight) == 1500);
    REQUIRE(c.pulseUs(kLeft) == 1500);
  }
  CHECK_FALSE(c.armed());
}

TEST_CASE("mutated valid frames either decode exactly or are refused") {
  FakePort port;
  Controller c(kEpoch, Trim{}, port);
  std::mt19937 rng(2);
  uint16_t seq = 1;
  for (int i = 0; i < 10000; ++i) {
    auto frame = speeds(0, 0, seq++);
    frame[rng() % (frame.size() - 1)] ^= static_cast<uint8_t>(1u << (rng() % 8));
    feed(c, frame, static_cast<uint32_t>(i));
    c.onByte(0, static_cast<uint32_t>(i));  // resynchronise if the flip removed a delimiter
    REQUIRE(c.speed(kRight) == 0);
    REQUIRE(c.speed(kLeft) == 0);
  }
}

TEST_CASE("firmware -> agent types sent to the firmware are counted and never answered") {
  FakePort port;
  Controller c(kEpoch, Trim{}, port);
  feed(c, speeds(0, 0, 1), 0);
  port.frames();
  feed(c, wire(MsgType::Ready, {1, 0, 1, 0}, 2), 1);
  feed(c, wire(MsgType::Error, {8, 0, 0}, 3), 2);
  CHECK(port.written.empty());
  CHECK(c.counters().otherDrops == 2);
}

TEST_CASE("every frame the firmware sends starts with a delimiter") {
  FakePort port;
  Controller c(kEpoch, Trim{}, port);
  c.begin(0);
  REQUIRE(!port.written.empty());
  CHECK(port.written.front() == 0x00);
  CHECK(port.written.back() == 0x00);
}

TEST_CASE("a sequence number exactly half the circle ahead counts as old") {
  FakePort port;
  Controller c(kEpoch, Trim{}, port);
  feed(c, speeds(0, 0, 0), 0);
  feed(c, speeds(1, 1, 0x8000), 1);
  CHECK(c.pulseUs(kRight) == 1500);
  feed(c, speeds(1, 1, 0x7FFF), 2);
  CHECK(c.pulseUs(kRight) == 2000);
}
