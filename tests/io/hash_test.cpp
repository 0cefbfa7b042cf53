// SPDX-License-Identifier: Apache-2.0
// io/hash: fnv1a64 against the published FNV-1a 64-bit test vectors, and
// chaining through the seed argument; splitmix64 against its reference sequence.
#include "io/hash.hpp"

#include <gtest/gtest.h>

#include <string>

namespace hisnegs::io {
namespace {

// Vectors from the FNV reference test suite (Fowler, Noll, Vo).
TEST(Hash, Fnv1a64OfKnownStrings) {
  EXPECT_EQ(fnv1a64(""), 0xcbf29ce484222325ull);
  EXPECT_EQ(fnv1a64("a"), 0xaf63dc4c8601ec8cull);
  EXPECT_EQ(fnv1a64("foobar"), 0x85944171f73967e8ull);
}

// Bytes are taken unsigned (0x80-0xff and NUL included): FNV-1a written out for
// these inputs, h = (h ^ byte) * 0x100000001b3 from 0xcbf29ce484222325.
TEST(Hash, Fnv1a64TakesBytesUnsigned) {
  EXPECT_EQ(fnv1a64(std::string("\xff\x80\0", 3)), 0xfad4091be587d31eull);
  EXPECT_EQ(fnv1a64("\xc3\xbc"), 0x0ac20a07b71807eaull);  // "ü" in UTF-8
}

// Hashing a then b with a's hash as the seed equals hashing a + b.
TEST(Hash, Fnv1a64ChainsThroughTheSeed) {
  const std::string a = "hisnegs ", b = std::string("state\0file", 10);
  EXPECT_EQ(fnv1a64(b.data(), b.size(), fnv1a64(a)), fnv1a64(a + b));
  EXPECT_NE(fnv1a64(a + b), fnv1a64(b + a));
  EXPECT_EQ(fnv1a64(nullptr, 0), fnv1a64(""));
}

// SplitMix64's first outputs from state 0 (the reference generator's sequence:
// state += 0x9E3779B97F4A7C15 before each mix), and unit_double's range.
TEST(Hash, SplitMix64MatchesTheReferenceSequence) {
  EXPECT_EQ(splitmix64(0), 0xe220a8397b1dcdafull);
  EXPECT_EQ(splitmix64(0x9E3779B97F4A7C15ull), 0x6e789e6aa1b965f4ull);
  EXPECT_EQ(unit_double(0), 0.0);
  EXPECT_LT(unit_double(~0ull), 1.0);
  EXPECT_GT(unit_double(~0ull), 1.0 - 1e-15);
}

}  // namespace
}  // namespace hisnegs::io
