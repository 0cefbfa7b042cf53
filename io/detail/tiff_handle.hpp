// SPDX-License-Identifier: Apache-2.0
// libtiff plumbing shared by the TIFF reader and writer: an owning handle whose
// diagnostics are collected (never printed) and appended to our messages, and
// small sample-type helpers. Includes tiffio.h: for io's .cpp files only.
#pragma once

#include <tiffio.h>
#include <unistd.h>

#include <cerrno>
#include <cstdarg>
#include <cstddef>
#include <filesystem>
#include <string>

#include "io/volume.hpp"

namespace hisnegs::io::detail {

inline constexpr double kGiB = 1024.0 * 1024.0 * 1024.0;

struct TiffMessages {
  std::string last_error;
  std::string last_warning;
  int errors = 0;
};

// Makes `messages` the sink of this thread's handle-less libtiff diagnostics
// (those that go through the global handler) and returns the previous sink.
// The thread_local itself stays private to tiff_handle.cpp.
TiffMessages* exchange_active_messages(TiffMessages* messages);

// Per-handle diagnostics sinks (TIFFOpenOptions) and the global fallback.
int on_tiff_error(TIFF*, void* user, const char* module, const char* fmt, va_list ap);
int on_tiff_warning(TIFF*, void* user, const char* module, const char* fmt, va_list ap);
void install_global_handlers();

// An open TIFF with its diagnostics. Not movable: libtiff holds &messages_.
// While active (from construction, or from activate()) its messages are this
// thread's sink for handle-less diagnostics; the destructor or deactivate() puts
// the previous sink back. A handle kept for later reads (TiffPageIndex's pool) is
// deactivated before it is put aside and activated by the thread that takes it,
// so no thread's sink ever points at a handle another thread owns or has freed.
class TiffHandle {
 public:
  // Takes ownership of `fd`. `mode` is "r", "w" or "w8"; `name` is for messages.
  TiffHandle(int fd, const std::filesystem::path& name, const char* mode, double max_single_alloc_bytes)
      : name_(name.string()) {
    install_global_handlers();
    previous_active_ = exchange_active_messages(&messages_);
    TIFFOpenOptions* opts = TIFFOpenOptionsAlloc();
    TIFFOpenOptionsSetErrorHandlerExtR(opts, on_tiff_error, &messages_);
    TIFFOpenOptionsSetWarningHandlerExtR(opts, on_tiff_warning, &messages_);
    if (max_single_alloc_bytes > 0 && max_single_alloc_bytes < 9e18) {
      TIFFOpenOptionsSetMaxSingleMemAlloc(opts, static_cast<tmsize_t>(max_single_alloc_bytes));
    }
    tif_ = TIFFFdOpenExt(fd, name.c_str(), mode, opts);
    const int err = errno;  // of a failed header write (ENOSPC): the caller reports it
    TIFFOpenOptionsFree(opts);
    if (!tif_) ::close(fd);
    errno = err;
  }
  ~TiffHandle() {
    close();
    if (active_) exchange_active_messages(previous_active_);
  }
  void deactivate() {
    if (active_) exchange_active_messages(previous_active_);
    active_ = false;
  }
  // Makes it this thread's sink again, with its messages cleared.
  void activate() {
    if (active_) return;
    messages_ = TiffMessages{};
    previous_active_ = exchange_active_messages(&messages_);
    active_ = true;
  }
  TiffHandle(const TiffHandle&) = delete;
  TiffHandle& operator=(const TiffHandle&) = delete;

  [[nodiscard]] TIFF* get() const { return tif_; }
  void close() {
    if (tif_) TIFFClose(tif_);
    tif_ = nullptr;
  }
  [[nodiscard]] const TiffMessages& messages() const { return messages_; }
  // " (libtiff: ...)" with the last error (or warning), or "".
  [[nodiscard]] std::string detail() const {
    std::string text = messages_.last_error.empty() ? messages_.last_warning : messages_.last_error;
    if (text.starts_with(name_ + ": ")) text.erase(0, name_.size() + 2);  // our message names the file already
    return text.empty() ? std::string() : " (libtiff: " + text + ")";
  }

 private:
  TIFF* tif_ = nullptr;
  std::string name_;
  TiffMessages messages_;
  TiffMessages* previous_active_ = nullptr;
  bool active_ = true;
};

// Bytes per sample of `type`.
std::size_t bytes_of(SampleType type);
// "NaN", "+Inf" or "-Inf".
const char* non_finite_text(float v);

}  // namespace hisnegs::io::detail
