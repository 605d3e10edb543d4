// The shared serial-link vectors (firmware/protocol/vectors.txt), also read by the Python suite.
#include <doctest/doctest.h>

#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "tumble_proto.h"

using namespace tumble;
using Bytes = std::vector<uint8_t>;

namespace {

Bytes unhex(const std::string& text) {
  Bytes out;
  if (text == "-") return out;
  for (size_t i = 0; i + 1 < text.size(); i += 2) out.push_back(static_cast<uint8_t>(std::stoi(text.substr(i, 2), nullptr, 16)));
  return out;
}

std::vector<std::vector<std::string>> rows(const std::string& kind) {
  std::ifstream file(VECTORS_PATH);
  REQUIRE(file.good());
  std::vector<std::vector<std::string>> out;
  std::string line;
  while (std::getline(file, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream words(line);
    std::vector<std::string> row;
    std::string w;
    while (words >> w) row.push_back(w);
    if (row[0] == kind) out.emplace_back(row.begin() + 1, row.end());
  }
  REQUIRE(!out.empty());
  return out;
}

Error errorByName(const std::string& name) {
  for (uint8_t i = 0; i < kErrorCount; ++i) {
    if (name == toString(static_cast<Error>(i))) return static_cast<Error>(i);
  }
  INFO("unknown error name: " << name);
  REQUIRE(false);
  return Error::Ok;
}

}  // namespace

TEST_CASE("CRC-16/MCRF4XX has the check value 0x6F91") {
  const char* check = "123456789";
  CHECK(crc16_mcrf4xx(reinterpret_cast<const uint8_t*>(check), 9) == 0x6F91);
}

TEST_CASE("crc vectors") {
  for (const auto& row : rows("crc")) {
    const Bytes data = unhex(row[0]);
    CHECK(crc16_mcrf4xx(data.data(), data.size()) == std::stoi(row[1], nullptr, 16));
  }
}

TEST_CASE("cobs vectors encode and decode") {
  for (const auto& row : rows("cobs")) {
    const Bytes raw = unhex(row[0]), enc = unhex(row[1]);
    Bytes out(raw.size() + raw.size() / 254 + 2);
    const size_t n = cobsEncode(raw.data(), raw.size(), out.data());
    CHECK(Bytes(out.begin(), out.begin() + static_cast<long>(n)) == enc);
    Bytes back(enc.size() + 1);
    size_t m = 0;
    REQUIRE(cobsDecode(enc.data(), enc.size(), back.data(), &m));
    CHECK(Bytes(back.begin(), back.begin() + static_cast<long>(m)) == raw);
  }
}

TEST_CASE("frame vectors encode to the same wire bytes and decode back") {
  for (const auto& row : rows("frame")) {
    Frame f;
    f.epoch = static_cast<uint16_t>(std::stoul(row[0]));
    f.seq = static_cast<uint16_t>(std::stoul(row[1]));
    f.type = static_cast<uint8_t>(std::stoul(row[2]));
    const Bytes payload = unhex(row[3]), wire = unhex(row[4]);
    f.len = static_cast<uint8_t>(payload.size());
    std::copy(payload.begin(), payload.end(), f.payload);
    uint8_t out[kMaxWire];
    const size_t n = encodeFrame(f, out);
    CHECK(Bytes(out, out + n) == wire);

    FrameReader reader;
    Frame got;
    FrameReader::Result last = FrameReader::Result::None;
    for (uint8_t b : wire) last = reader.feed(b, got);
    REQUIRE(last == FrameReader::Result::Frame);
    CHECK(got.epoch == f.epoch);
    CHECK(got.seq == f.seq);
    CHECK(got.type == f.type);
    CHECK(Bytes(got.payload, got.payload + got.len) == payload);
  }
}

TEST_CASE("reject vectors are refused for the stated reason") {
  for (const auto& row : rows("reject")) {
    const Bytes body = unhex(row[0]);
    const Error expected = errorByName(row[1]);
    Frame f;
    CAPTURE(row[0]);
    CHECK(toString(decodeBody(body.data(), body.size(), f)) == std::string(toString(expected)));
    FrameReader reader;
    FrameReader::Result last = FrameReader::Result::None;
    for (uint8_t b : body) last = reader.feed(b, f);
    last = reader.feed(0, f);
    CHECK(last == FrameReader::Result::Error);
    CHECK(toString(reader.error()) == std::string(toString(expected)));
  }
}

TEST_CASE("the message table matches the shared one") {
  for (const auto& r : rows("msg")) {
    const uint8_t type = static_cast<uint8_t>(std::stoi(r[0]));
    INFO("type " << int(type));
    CHECK(payloadSize(type) == std::stoi(r[2]));
    CHECK(isForFirmware(type) == (r[1] == "to_firmware"));
  }
}

TEST_CASE("STATUS payloads pack to the shared bytes") {
  for (const auto& r : rows("status")) {
    StatusPayload s;
    s.uptimeMs = static_cast<uint32_t>(std::stoul(r[0]));
    s.right = static_cast<int8_t>(std::stoi(r[1]));
    s.left = static_cast<int8_t>(std::stoi(r[2]));
    s.flags = static_cast<uint8_t>(std::stoi(r[3]));
    s.framesOk = static_cast<uint16_t>(std::stoi(r[4]));
    s.crcErrors = static_cast<uint16_t>(std::stoi(r[5]));
    s.otherDrops = static_cast<uint16_t>(std::stoi(r[6]));
    s.watchdogTrips = static_cast<uint16_t>(std::stoi(r[7]));
    s.lastSeq = static_cast<uint16_t>(std::stoi(r[8]));
    uint8_t out[StatusPayload::kSize];
    s.pack(out);
    CHECK(Bytes(out, out + StatusPayload::kSize) == unhex(r[9]));
  }
}

TEST_CASE("INFO payloads pack to the shared bytes") {
  const auto infos = rows("info");
  REQUIRE_FALSE(infos.empty());
  for (const auto& r : infos) {
    InfoPayload info;
    info.protocol = static_cast<uint8_t>(std::stoi(r[0]));
    info.major = static_cast<uint8_t>(std::stoi(r[1]));
    info.minor = static_cast<uint8_t>(std::stoi(r[2]));
    info.patch = static_cast<uint8_t>(std::stoi(r[3]));
    info.neutralUs[0] = static_cast<uint16_t>(std::stoi(r[4]));
    info.direction[0] = static_cast<int8_t>(std::stoi(r[5]));
    info.neutralUs[1] = static_cast<uint16_t>(std::stoi(r[6]));
    info.direction[1] = static_cast<int8_t>(std::stoi(r[7]));
    uint8_t out[InfoPayload::kSize];
    info.pack(out);
    CHECK(Bytes(out, out + InfoPayload::kSize) == unhex(r[8]));
  }
}
