#pragma once
// The form of a candidate term in the return-rate and range-noise loops. The loops build their
// candidates with it and write it by name (console, JSON and Markdown reports); nothing parses it.
//   table   one value per bin of the feature
//   window  one value inside a contiguous run of bins (circular for azimuth), one outside
//   step    (returns) one value per class beyond a fitted range
//   growth  (range noise, range only) an extra spread c r added in quadrature
namespace lidarsim::qualify {

enum class TermForm { table, window, step, growth };

inline const char* to_string(TermForm f) {
  switch (f) {
    case TermForm::table: return "table";
    case TermForm::window: return "window";
    case TermForm::step: return "step";
    case TermForm::growth: return "growth";
  }
  return "?";
}

}  // namespace lidarsim::qualify
