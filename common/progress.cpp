#include "common/progress.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>

namespace lidarsim {

ProgressBar::ProgressBar(std::string label, long total, bool enabled)
    : label_(std::move(label)), total_(std::max(1L, total)), enabled_(enabled) {
  start_ = last_draw_ = std::chrono::steady_clock::now();
}

std::string format_duration(double seconds) {
  if (!std::isfinite(seconds) || seconds < 0) return "--:--";
  const long s = std::lround(seconds);
  char buf[32];
  if (s >= 3600)
    std::snprintf(buf, sizeof buf, "%ld:%02ld:%02ld", s / 3600, (s / 60) % 60, s % 60);
  else
    std::snprintf(buf, sizeof buf, "%02ld:%02ld", s / 60, s % 60);
  return buf;
}

void ProgressBar::draw(long done, const std::string& status) {
  const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  const double fraction = std::clamp(static_cast<double>(done) / total_, 0.0, 1.0);
  const double eta = done > 0 ? elapsed * (total_ - done) / done : NAN;
  constexpr int kWidth = 28;
  const int filled = static_cast<int>(fraction * kWidth);
  std::string bar(filled, '#');
  bar.resize(kWidth, '.');
  // \r redraws in place on a terminal; in a log each update is its own line.
  const bool tty = ::isatty(STDERR_FILENO);
  std::fprintf(stderr, "%s%s [%s] %ld/%ld %3.0f%% elapsed %s eta %s %s%s", tty ? "\r" : "", label_.c_str(),
               bar.c_str(), done, total_, fraction * 100, format_duration(elapsed).c_str(),
               format_duration(eta).c_str(), status.c_str(), tty ? "\033[K" : "\n");
  std::fflush(stderr);
}

void ProgressBar::update(long done, const std::string& status) {
  if (!enabled_) return;
  const auto now = std::chrono::steady_clock::now();
  const bool tty = ::isatty(STDERR_FILENO);
  const double since = std::chrono::duration<double>(now - last_draw_).count();
  if (done < total_ && since < (tty ? 0.1 : 5.0)) return;
  last_draw_ = now;
  draw(done, status);
}

void ProgressBar::finish(const std::string& status) {
  if (!enabled_) return;
  draw(total_, status);
  if (::isatty(STDERR_FILENO)) std::fputc('\n', stderr);
}

}  // namespace lidarsim
