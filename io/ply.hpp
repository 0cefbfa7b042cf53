// SPDX-License-Identifier: Apache-2.0
// Generic PLY tables: elements of scalar properties held as packed rows, read
// from ascii / binary (either endianness) PLY 1.0 and written as binary little
// endian. Knows nothing of Gaussians (gmf/core/checkpoint.hpp maps them onto this).
#pragma once

#include <bit>
#include <cmath>
#include <concepts>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <limits>
#include <memory>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <type_traits>
#include <utility>
#include <vector>

namespace hisnegs::io {

static_assert(std::endian::native == std::endian::little,
              "PlyElement keeps rows in native byte order, which must be little endian");

// The scalar property types of PLY 1.0. (List properties are not supported.)
enum class PlyType : std::uint8_t { kInt8, kUint8, kInt16, kUint16, kInt32, kUint32, kFloat32, kFloat64 };

// The classic PLY name, as write_ply writes it: char uchar short ushort int uint float double.
[[nodiscard]] std::string_view to_string(PlyType type);
// Bytes per value: 1, 1, 2, 2, 4, 4, 4, 8.
[[nodiscard]] std::size_t size_of(PlyType type);
// Parses a classic name or its alias (int8 uint8 int16 uint16 int32 uint32 float32
// float64); nullopt for anything else.
[[nodiscard]] std::optional<PlyType> parse_ply_type(std::string_view name);

// The C++ types that are stored exactly as one PlyType.
template <class T>
concept PlyScalar = std::same_as<T, std::int8_t> || std::same_as<T, std::uint8_t> || std::same_as<T, std::int16_t> ||
    std::same_as<T, std::uint16_t> || std::same_as<T, std::int32_t> || std::same_as<T, std::uint32_t> ||
    std::same_as<T, float> || std::same_as<T, double>;
// Any number a column can be converted to or from (bool excluded).
template <class T>
concept PlyConvertible = std::is_arithmetic_v<T> && !std::same_as<std::remove_cv_t<T>, bool>;

template <PlyScalar T>
[[nodiscard]] constexpr PlyType ply_type_of() {
  if constexpr (std::same_as<T, std::int8_t>)
    return PlyType::kInt8;
  else if constexpr (std::same_as<T, std::uint8_t>)
    return PlyType::kUint8;
  else if constexpr (std::same_as<T, std::int16_t>)
    return PlyType::kInt16;
  else if constexpr (std::same_as<T, std::uint16_t>)
    return PlyType::kUint16;
  else if constexpr (std::same_as<T, std::int32_t>)
    return PlyType::kInt32;
  else if constexpr (std::same_as<T, std::uint32_t>)
    return PlyType::kUint32;
  else if constexpr (std::same_as<T, float>)
    return PlyType::kFloat32;
  else
    return PlyType::kFloat64;
}

struct PlyProperty {
  std::string name;
  PlyType type = PlyType::kFloat32;
  friend bool operator==(const PlyProperty&, const PlyProperty&) = default;
};

namespace detail {
// Leaves bytes uninitialized on resize, so reading a file into a row buffer does
// not first zero it (one pass over memory instead of two).
template <class T>
struct DefaultInitAllocator : std::allocator<T> {
  template <class U>
  struct rebind {
    using other = DefaultInitAllocator<U>;
  };
  using std::allocator<T>::allocator;
  template <class U, class... Args>
  void construct(U* p, Args&&... args) {
    if constexpr (sizeof...(Args) == 0) {
      ::new (static_cast<void*>(p)) U;
    } else {
      ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
    }
  }
};
using ByteBuffer = std::vector<std::byte, DefaultInitAllocator<std::byte>>;

// Calls f(S{}) with S the C++ type stored for `type`.
template <class F>
decltype(auto) visit_ply_type(PlyType type, F&& f) {
  switch (type) {
    case PlyType::kInt8:
      return f(std::int8_t{});
    case PlyType::kUint8:
      return f(std::uint8_t{});
    case PlyType::kInt16:
      return f(std::int16_t{});
    case PlyType::kUint16:
      return f(std::uint16_t{});
    case PlyType::kInt32:
      return f(std::int32_t{});
    case PlyType::kUint32:
      return f(std::uint32_t{});
    case PlyType::kFloat32:
      return f(float{});
    case PlyType::kFloat64:
      return f(double{});
  }
  throw std::logic_error("invalid PlyType");
}

// Converts `value` to To if it is exactly representable (integers) or, for a
// floating-point To, always (rounding to nearest; a double too large for float
// becomes ±inf). Returns false for a non-integral, out-of-range or NaN value
// headed for an integer type: columns are never clamped.
template <class To, class From>
[[nodiscard]] bool convert_value(From value, To& out) {
  if constexpr (std::is_same_v<To, From>) {
    out = value;
    return true;
  } else if constexpr (std::is_floating_point_v<To>) {
    if constexpr (std::is_floating_point_v<From> && sizeof(From) > sizeof(To)) {
      // An out-of-range narrowing cast is undefined behaviour; make it the ±inf IEEE rounding gives.
      if (std::isfinite(value) && std::abs(value) > static_cast<From>(std::numeric_limits<To>::max())) {
        out = std::copysign(std::numeric_limits<To>::infinity(), static_cast<To>(value > 0 ? 1 : -1));
        return true;
      }
    }
    out = static_cast<To>(value);
    return true;
  } else if constexpr (std::is_integral_v<From>) {
    if (!std::in_range<To>(value)) return false;
    out = static_cast<To>(value);
    return true;
  } else {
    // Both bounds are powers of two (or 0), exact in any floating type.
    const From lo = static_cast<From>(std::numeric_limits<To>::min());
    const From hi = std::ldexp(From{1}, std::numeric_limits<To>::digits);
    if (!(value >= lo && value < hi) || std::trunc(value) != value) return false;
    out = static_cast<To>(value);
    return true;
  }
}

// "int32", "uint64", "float64", ... for messages.
template <class T>
[[nodiscard]] std::string arithmetic_name() {
  const char* kind = std::is_floating_point_v<T> ? "float" : std::is_signed_v<T> ? "int" : "uint";
  return kind + std::to_string(8 * sizeof(T));
}
}  // namespace detail

// One PLY element: `count` rows of `properties`, stored packed row by row exactly
// as binary little-endian PLY lays them out (no padding), so reading and writing
// is one bulk copy. Invariant: bytes().size() == count() * row_size().
class PlyElement {
 public:
  PlyElement() = default;
  // An element with no properties and no rows; add_column() sets the count.
  explicit PlyElement(std::string name);
  // `count` zero-filled rows of `properties`. Throws std::invalid_argument for a
  // negative count, duplicate or empty property names, or a size that overflows.
  PlyElement(std::string name, std::int64_t count, std::vector<PlyProperty> properties);

  [[nodiscard]] const std::string& name() const { return name_; }
  [[nodiscard]] std::int64_t count() const { return count_; }
  [[nodiscard]] const std::vector<PlyProperty>& properties() const { return properties_; }
  [[nodiscard]] std::size_t row_size() const { return row_size_; }  // bytes per row
  // Byte offset of property `prop` inside a row.
  [[nodiscard]] std::size_t offset(std::size_t prop) const { return offsets_.at(prop); }
  // Index of the property called `name`, if any.
  [[nodiscard]] std::optional<std::size_t> find_property(std::string_view name) const;

  // The packed rows, little endian: row r, property p starts at r * row_size() + offset(p).
  [[nodiscard]] std::span<const std::byte> bytes() const { return {bytes_.data(), bytes_.size()}; }
  [[nodiscard]] std::span<std::byte> bytes() { return {bytes_.data(), bytes_.size()}; }

  // One value converted to double (exact for every PLY type). Throws
  // std::out_of_range for a bad row or property index. Slow path; use column_as for bulk.
  [[nodiscard]] double value(std::int64_t row, std::size_t prop) const;

  // All `count()` values of a property converted to T (see detail::convert_value).
  // Throws std::out_of_range if the property does not exist (callers reading user
  // files check find_property() first and report the file), std::range_error if
  // a value is not representable in an integer T.
  template <PlyConvertible T>
  [[nodiscard]] std::vector<T> column_as(std::string_view name) const {
    return column_as<T>(require_property(name));
  }
  template <PlyConvertible T>
  [[nodiscard]] std::vector<T> column_as(std::size_t prop) const;

  // Overwrites property `prop` with `values` (exactly count() of them), converted
  // to the property's type. Throws std::invalid_argument on a size mismatch,
  // std::out_of_range for a bad index, std::range_error for a value the
  // property's integer type cannot hold.
  template <PlyConvertible T>
  void set_column(std::size_t prop, std::span<const T> values);

  // Appends a property of type `type` holding `values`. On an element without
  // properties this sets count() = values.size(); otherwise values.size() must
  // equal count(). Repacks the rows (O(count × row_size)). Throws like set_column
  // and std::invalid_argument for an empty or duplicate name.
  template <PlyConvertible T>
  void add_column(std::string name, PlyType type, std::span<const T> values);
  // Same, with the property type that stores T exactly.
  template <PlyScalar T>
  void add_column(std::string name, std::span<const T> values) {
    add_column<T>(std::move(name), ply_type_of<T>(), values);
  }

  friend bool operator==(const PlyElement&, const PlyElement&) = default;

 private:
  friend class PlyReader;
  struct Uninitialized {};
  PlyElement(std::string name, std::int64_t count, std::vector<PlyProperty> properties, Uninitialized);
  [[nodiscard]] std::size_t require_property(std::string_view name) const;
  void require_index(std::size_t prop) const;
  [[noreturn]] void throw_unrepresentable(std::size_t prop, std::int64_t row, double value,
                                          const std::string& target) const;
  // A copy of *this with one more (zeroed) property; `count_if_first` is the row
  // count when *this has no properties yet.
  [[nodiscard]] PlyElement with_property(std::string name, PlyType type, std::int64_t count_if_first) const;

  std::string name_;
  std::int64_t count_ = 0;
  std::vector<PlyProperty> properties_;
  std::vector<std::size_t> offsets_;
  std::size_t row_size_ = 0;
  detail::ByteBuffer bytes_;
};

// A whole PLY file: header comments and obj_info lines (text after the keyword
// and one space, verbatim), then the elements in file order.
struct PlyTable {
  std::vector<std::string> comments;
  std::vector<std::string> obj_info;
  std::vector<PlyElement> elements;

  // The element called `name`, or nullptr.
  [[nodiscard]] const PlyElement* find(std::string_view name) const;
  [[nodiscard]] PlyElement* find(std::string_view name);
  friend bool operator==(const PlyTable&, const PlyTable&) = default;
};

// Reads an ascii, binary_little_endian or binary_big_endian PLY 1.0 file.
// Throws InputError, one line "PATH: problem", for: a missing file or a folder,
// no "ply" magic line, a malformed / unknown header line (quoted, with its line
// number), an unknown format, version or property type, list properties, a bad
// element count, a missing end_header, data cut short ("expected N bytes of
// vertex data, file has M"), bad ascii values, and any data after the last
// element other than trailing whitespace in ascii files. Element sizes are
// checked against the file size before anything is allocated.
[[nodiscard]] PlyTable read_ply(const std::filesystem::path& path);

// Writes `table` as binary_little_endian PLY 1.0 (comments, then obj_info, then
// the elements), atomically (io::AtomicFile). Throws std::invalid_argument for a
// comment / obj_info with a line break or an element / property name that is
// empty or contains whitespace (nothing is left behind: the temporary file is
// removed); InputError / std::runtime_error if the file cannot be written.
void write_ply(const std::filesystem::path& path, const PlyTable& table);

// Writes a binary_little_endian PLY of one element whose rows arrive in pieces (a
// model too large to hold at once): the header (the comments, then the element's
// name, count and properties) at once, then append() the rows, then commit(),
// which checks that exactly `count` rows came and renames the file into place
// (io::AtomicFile: destroyed without commit(), nothing is left). The bytes equal
// write_ply's for the same table. Throws as write_ply does, and std::logic_error for
// rows that are not whole or more or fewer than `count`.
class PlyRowWriter {
 public:
  PlyRowWriter(const std::filesystem::path& path, const std::vector<std::string>& comments, const std::string& element,
               std::int64_t count, const std::vector<PlyProperty>& properties);
  ~PlyRowWriter();
  PlyRowWriter(const PlyRowWriter&) = delete;
  PlyRowWriter& operator=(const PlyRowWriter&) = delete;
  // `bytes` holds whole rows of the element (a multiple of its row size).
  void append(std::span<const std::byte> bytes);
  void commit();

 private:
  struct State;
  std::unique_ptr<State> state_;
};

// ----- implementation of the templates -----

template <PlyConvertible T>
std::vector<T> PlyElement::column_as(std::size_t prop) const {
  require_index(prop);
  std::vector<T> out(static_cast<std::size_t>(count_));
  if (out.empty()) return out;  // no rows, no buffer: null + offset would be undefined
  const std::byte* p = bytes_.data() + offsets_[prop];
  detail::visit_ply_type(properties_[prop].type, [&](auto tag) {
    using S = decltype(tag);
    for (std::size_t r = 0; r < out.size(); ++r, p += row_size_) {
      S v;
      std::memcpy(&v, p, sizeof v);
      if (!detail::convert_value(v, out[r])) {
        throw_unrepresentable(prop, static_cast<std::int64_t>(r), static_cast<double>(v), detail::arithmetic_name<T>());
      }
    }
  });
  return out;
}

template <PlyConvertible T>
void PlyElement::set_column(std::size_t prop, std::span<const T> values) {
  require_index(prop);
  if (values.size() != static_cast<std::size_t>(count_)) {
    throw std::invalid_argument("PLY element '" + name_ + "' property '" + properties_[prop].name + "': " +
                                std::to_string(values.size()) + " values for " + std::to_string(count_) + " rows");
  }
  if (values.empty()) return;  // no rows, no buffer: null + offset would be undefined
  std::byte* p = bytes_.data() + offsets_[prop];
  detail::visit_ply_type(properties_[prop].type, [&](auto tag) {
    using S = decltype(tag);
    for (std::size_t r = 0; r < values.size(); ++r, p += row_size_) {
      S v{};
      if (!detail::convert_value(values[r], v)) {
        throw_unrepresentable(prop, static_cast<std::int64_t>(r), static_cast<double>(values[r]),
                              std::string(to_string(properties_[prop].type)));
      }
      std::memcpy(p, &v, sizeof v);
    }
  });
}

template <PlyConvertible T>
void PlyElement::add_column(std::string name, PlyType type, std::span<const T> values) {
  if (!properties_.empty() && values.size() != static_cast<std::size_t>(count_)) {
    throw std::invalid_argument("PLY element '" + name_ + "': column '" + name + "' has " +
                                std::to_string(values.size()) + " values for " + std::to_string(count_) + " rows");
  }
  // Build the repacked element aside and swap it in only once every value
  // converted, so a throw leaves *this unchanged.
  PlyElement next = with_property(std::move(name), type, static_cast<std::int64_t>(values.size()));
  next.set_column(next.properties_.size() - 1, values);
  *this = std::move(next);
}

}  // namespace hisnegs::io
