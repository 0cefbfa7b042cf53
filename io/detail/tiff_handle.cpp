// SPDX-License-Identifier: Apache-2.0
// libtiff diagnostics routing (per-handle and global handlers) and sample helpers.
#include "io/detail/tiff_handle.hpp"

#include <cmath>
#include <cstdio>
#include <mutex>

#include "io/error.hpp"

namespace hisnegs::io::detail {

namespace {

// The TiffMessages of the handle this thread is working with, for the few
// libtiff diagnostics that are not tied to a handle (they use the global handler).
thread_local TiffMessages* t_active_messages = nullptr;

std::string format_message(const char* module, const char* fmt, va_list ap) {
  char text[512];
  std::vsnprintf(text, sizeof text, fmt, ap);
  return printable(module && *module ? std::string(module) + ": " + text : std::string(text));
}

TIFFErrorHandler g_previous_error_handler = nullptr;
TIFFErrorHandler g_previous_warning_handler = nullptr;

void on_global_error(const char* module, const char* fmt, va_list ap) {
  if (t_active_messages) {
    t_active_messages->last_error = format_message(module, fmt, ap);
    ++t_active_messages->errors;
  } else if (g_previous_error_handler) {
    g_previous_error_handler(module, fmt, ap);
  }
}

void on_global_warning(const char* module, const char* fmt, va_list ap) {
  if (t_active_messages) {
    t_active_messages->last_warning = format_message(module, fmt, ap);
  } else if (g_previous_warning_handler) {
    g_previous_warning_handler(module, fmt, ap);
  }
}

}  // namespace

TiffMessages* exchange_active_messages(TiffMessages* messages) {
  TiffMessages* previous = t_active_messages;
  t_active_messages = messages;
  return previous;
}

int on_tiff_error(TIFF*, void* user, const char* module, const char* fmt, va_list ap) {
  auto* m = static_cast<TiffMessages*>(user);
  m->last_error = format_message(module, fmt, ap);
  ++m->errors;
  return 1;  // handled: do not call the global (stderr) handlers
}

int on_tiff_warning(TIFF*, void* user, const char* module, const char* fmt, va_list ap) {
  static_cast<TiffMessages*>(user)->last_warning = format_message(module, fmt, ap);
  return 1;
}

// Global handlers catch handle-less diagnostics while one of our handles is
// active on this thread and forward everything else to the previous handlers.
void install_global_handlers() {
  static std::once_flag once;
  std::call_once(once, [] {
    g_previous_error_handler = TIFFSetErrorHandler(on_global_error);
    g_previous_warning_handler = TIFFSetWarningHandler(on_global_warning);
  });
}

std::size_t bytes_of(SampleType type) {
  switch (type) {
    case SampleType::kUint8:
      return 1;
    case SampleType::kUint16:
      return 2;
    case SampleType::kFloat32:
      return 4;
  }
  return 4;
}

const char* non_finite_text(float v) { return std::isnan(v) ? "NaN" : (v > 0 ? "+Inf" : "-Inf"); }

}  // namespace hisnegs::io::detail
