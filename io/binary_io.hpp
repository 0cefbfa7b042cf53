// SPDX-License-Identifier: Apache-2.0
// A little-endian binary record of trivially copyable values, arrays and strings
// (BinaryWriter), and its checked reader (BinaryReader) whose every failure is one
// io::InputError line naming the source. For small state files (training and
// optimizer state); not a file format of its own.
#pragma once

#include <bit>
#include <cstdint>
#include <cstring>
#include <span>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

#include "io/error.hpp"

namespace hisnegs::io {

static_assert(std::endian::native == std::endian::little, "binary records are little-endian");

class BinaryWriter {
 public:
  template <class T>
  void put(const T& value) {
    static_assert(std::is_trivially_copyable_v<T>);
    bytes_.append(reinterpret_cast<const char*>(&value), sizeof(T));
  }
  // A uint64 count, then the values.
  template <class T>
  void put_array(std::span<const T> values) {
    static_assert(std::is_trivially_copyable_v<T>);
    put<std::uint64_t>(values.size());
    if (!values.empty()) bytes_.append(reinterpret_cast<const char*>(values.data()), values.size_bytes());
  }
  void put_string(std::string_view text) { put_array(std::span<const char>(text.data(), text.size())); }
  [[nodiscard]] std::string take() { return std::move(bytes_); }

 private:
  std::string bytes_;
};

// Reads what BinaryWriter wrote. `what` prefixes every message ("training state").
class BinaryReader {
 public:
  BinaryReader(std::string_view bytes, std::string source, std::string what)
      : bytes_(bytes), source_(std::move(source)), what_(std::move(what)) {}
  template <class T>
  T get() {
    static_assert(std::is_trivially_copyable_v<T>);
    T value;
    need(sizeof(T));
    std::memcpy(&value, bytes_.data() + at_, sizeof(T));
    at_ += sizeof(T);
    return value;
  }
  // An array written by put_array that must hold exactly `expected` values.
  template <class T>
  std::vector<T> get_array(std::size_t expected) {
    const auto n = get<std::uint64_t>();
    if (n != expected) fail("array of " + std::to_string(n) + " values, expected " + std::to_string(expected));
    need(n * sizeof(T));
    std::vector<T> values(n);
    if (n > 0) std::memcpy(values.data(), bytes_.data() + at_, n * sizeof(T));  // data() may be null when empty
    at_ += n * sizeof(T);
    return values;
  }
  std::string get_string() {
    const auto n = get<std::uint64_t>();
    need(n);
    std::string text(bytes_.substr(at_, n));
    at_ += n;
    return text;
  }
  [[nodiscard]] bool done() const { return at_ == bytes_.size(); }
  [[noreturn]] void fail(const std::string& problem) const { fail_input(source_, what_ + ": " + problem); }

 private:
  void need(std::uint64_t n) const {
    if (n > bytes_.size() - at_) fail("truncated");
  }
  std::string_view bytes_;
  std::string source_, what_;
  std::size_t at_ = 0;
};

}  // namespace hisnegs::io
