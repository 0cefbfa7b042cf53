// SPDX-License-Identifier: Apache-2.0
// io/binary_io: values, arrays and strings round trip through BinaryWriter and
// BinaryReader; every truncation and a wrong array size are one-line
// io::InputErrors naming the source, what is read, and the problem.
#include "io/binary_io.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <limits>
#include <span>
#include <string>
#include <vector>

#include "io/error.hpp"

namespace hisnegs::io {
namespace {

struct Pod {
  std::int32_t a;
  float b;
  double c;
};

// The record the tests read back: one of each kind.
std::string record() {
  BinaryWriter w;
  w.put<std::int64_t>(-1234567890123);
  w.put<double>(std::numeric_limits<double>::denorm_min());
  w.put<std::uint8_t>(200);
  w.put(Pod{-7, 1.5f, -2.25});
  const std::vector<float> floats = {0.5f, -0.0f, std::numeric_limits<float>::infinity()};
  w.put_array(std::span<const float>(floats));
  w.put_array(std::span<const std::uint64_t>());
  w.put_string(std::string("tab\there\0nul ü", 15));
  w.put_string("");
  return w.take();
}

TEST(BinaryIo, ValuesArraysAndStringsRoundTrip) {
  const std::string bytes = record();
  BinaryReader r(bytes, "state.bin", "training state");
  EXPECT_EQ(r.get<std::int64_t>(), -1234567890123);
  EXPECT_EQ(r.get<double>(), std::numeric_limits<double>::denorm_min());
  EXPECT_EQ(r.get<std::uint8_t>(), 200);
  const Pod p = r.get<Pod>();
  EXPECT_EQ(p.a, -7);
  EXPECT_EQ(p.b, 1.5f);
  EXPECT_EQ(p.c, -2.25);
  const std::vector<float> floats = r.get_array<float>(3);
  ASSERT_EQ(floats.size(), 3u);
  EXPECT_EQ(floats[0], 0.5f);
  EXPECT_TRUE(std::signbit(floats[1]));
  EXPECT_EQ(floats[2], std::numeric_limits<float>::infinity());
  EXPECT_TRUE(r.get_array<std::uint64_t>(0).empty());
  EXPECT_FALSE(r.done());
  EXPECT_EQ(r.get_string(), std::string("tab\there\0nul ü", 15));
  EXPECT_EQ(r.get_string(), "");
  EXPECT_TRUE(r.done());
}

// The layout is fixed: little-endian values, arrays as a uint64 count then the values.
TEST(BinaryIo, LayoutIsCountThenLittleEndianValues) {
  BinaryWriter w;
  w.put<std::uint32_t>(0x04030201u);
  const std::vector<std::uint16_t> v = {0x0605};
  w.put_array(std::span<const std::uint16_t>(v));
  EXPECT_EQ(w.take(), std::string("\x01\x02\x03\x04\x01\0\0\0\0\0\0\0\x05\x06", 14));
}

// Every proper prefix of the record fails on the read that runs past its end,
// with "SOURCE: WHAT: truncated".
TEST(BinaryIo, TruncatedInputIsAnInputErrorNamingTheSource) {
  const std::string bytes = record();
  for (std::size_t n = 0; n < bytes.size(); ++n) {
    BinaryReader r(std::string_view(bytes).substr(0, n), "runs/a/state.bin", "training state");
    try {
      (void)r.get<std::int64_t>();
      (void)r.get<double>();
      (void)r.get<std::uint8_t>();
      (void)r.get<Pod>();
      (void)r.get_array<float>(3);
      (void)r.get_array<std::uint64_t>(0);
      (void)r.get_string();
      (void)r.get_string();
      ADD_FAILURE() << "a prefix of " << n << " of " << bytes.size() << " bytes read completely";
    } catch (const InputError& e) {
      EXPECT_EQ(std::string(e.what()), "runs/a/state.bin: training state: truncated") << "prefix " << n;
    }
  }
}

// A count far beyond the data (a corrupt length) is "truncated", not an allocation.
TEST(BinaryIo, HugeCountsAreTruncatedNotAllocated) {
  BinaryWriter w;
  w.put<std::uint64_t>(std::uint64_t{1} << 60);
  w.put<std::uint32_t>(0);
  const std::string bytes = w.take();
  BinaryReader strings(bytes, "s.bin", "state");
  EXPECT_THROW((void)strings.get_string(), InputError);
  BinaryReader arrays(bytes, "s.bin", "state");
  EXPECT_THROW((void)arrays.get_array<double>(std::size_t{1} << 60), InputError);
}

TEST(BinaryIo, WrongArraySizeNamesBothSizes) {
  const std::vector<double> four = {1, 2, 3, 4};
  BinaryWriter w;
  w.put_array(std::span<const double>(four));
  const std::string bytes = w.take();
  for (const std::size_t expected : {std::size_t{3}, std::size_t{5}}) {
    BinaryReader r(bytes, "opt.bin", "optimizer state");
    try {
      (void)r.get_array<double>(expected);
      ADD_FAILURE() << "read 4 values as " << expected;
    } catch (const InputError& e) {
      EXPECT_EQ(std::string(e.what()),
                "opt.bin: optimizer state: array of 4 values, expected " + std::to_string(expected));
    }
  }
}

TEST(BinaryIo, FailNamesSourceWhatAndProblem) {
  const BinaryReader r("", "x/y.bin", "trainer state");
  try {
    r.fail("version 9 unknown");
    ADD_FAILURE() << "fail() returned";
  } catch (const InputError& e) {
    EXPECT_EQ(std::string(e.what()), "x/y.bin: trainer state: version 9 unknown");
  }
}

}  // namespace
}  // namespace hisnegs::io
