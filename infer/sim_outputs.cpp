#include "infer/sim_outputs.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <numbers>

#include <nlohmann/json.hpp>

#include "common/atomic_file.h"
#include "common/error.h"
#include "common/image.h"
#include "common/plot.h"
#include "data/point_cloud_io.h"
#include "pgm/materials.h"
#include "sensor/fov.h"
#include "sensor/lanes.h"

namespace lidarsim::infer {
namespace {

constexpr double kRadToDeg = 180.0 / std::numbers::pi;

// Bird's-eye view colours: one place for what the map draws and what its legend says.
constexpr Rgb kBevBackground{20, 20, 24}, kBevRule{70, 70, 78}, kBevPoint{90, 90, 90}, kBevLane{230, 230, 230},
    kBevTruth{60, 200, 60}, kBevTruthOccluded{30, 100, 30}, kBevReported{230, 50, 50}, kBevCoasting{255, 160, 0},
    kBevFalsePositive{230, 60, 230}, kBevSensor{255, 255, 255};
constexpr TextStyle kBevText{{225, 225, 225}, kBevBackground, {110, 110, 118}, 2};

std::string frame_name(const char* stem, int index, const char* ext) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%s_%04d.%s", stem, index, ext);
  return buf;
}

const char* lane_type_name(sensor::LaneType t) {
  switch (t) {
    case sensor::LaneType::Solid: return "solid";
    case sensor::LaneType::Dashed: return "dashed";
    case sensor::LaneType::RoadEdge: return "road_edge";
  }
  return "?";
}

nlohmann::json object_json(const sensor::Object& o, int truth_id, const char* extra_key = nullptr, bool extra = false) {
  nlohmann::json j = {{"id", o.id},
                      {"truth_id", truth_id},
                      {"class", sensor::to_string(o.cls)},
                      {"x", o.position.x()},
                      {"y", o.position.y()},
                      {"z", o.position.z()},
                      {"l", o.size.x()},
                      {"w", o.size.y()},
                      {"h", o.size.z()},
                      {"heading_deg", o.heading * kRadToDeg},
                      {"vx", o.velocity.x()},
                      {"vy", o.velocity.y()},
                      {"visible_fraction", o.visible_fraction},
                      {"score", o.score}};
  if (extra_key) j[extra_key] = extra;
  return j;
}

void csv_row(std::string& s, const char* source, const sensor::Object& o, int truth_id, bool coasting) {
  char line[512];
  std::snprintf(line, sizeof line, "%s,%d,%d,%s,%.4f,%.4f,%.4f,%.3f,%.3f,%.3f,%.3f,%.4f,%.4f,%.4f,%.4f,%d\n", source,
                o.id, truth_id, sensor::to_string(o.cls).c_str(), o.position.x(), o.position.y(), o.position.z(),
                o.size.x(), o.size.y(), o.size.z(), o.heading * kRadToDeg, o.velocity.x(), o.velocity.y(),
                o.visible_fraction, o.score, coasting ? 1 : 0);
  s += line;
}

// Class and material ids as categorical colours, empty cells black.
Image category_image(const float* values, const float* mask, int width, int height) {
  Image img(width, height);
  for (int i = 0; i < width * height; ++i)
    if (mask[i] > 0) img.pixels[i] = colormap_category(static_cast<int>(values[i]));
  return img;
}

// Key of a categorical channel: the ids present, most cells first, named as in pgm/materials.h.
std::vector<LegendEntry> category_key(const float* values, const float* mask, std::size_t cells,
                                      const std::string& (*name)(int)) {
  std::map<int, long> count;
  for (std::size_t i = 0; i < cells; ++i)
    if (mask[i] > 0) ++count[static_cast<int>(values[i])];
  std::vector<std::pair<long, int>> by_count;
  for (const auto& [id, n] : count) by_count.emplace_back(-n, id);
  std::sort(by_count.begin(), by_count.end());
  std::vector<LegendEntry> key;
  for (const auto& [minus_n, id] : by_count) {
    std::string label = name(id);
    std::replace(label.begin(), label.end(), '_', ' ');
    key.push_back({label, colormap_category(id), Mark::box});
  }
  return key;
}

// A categorical channel under a band with its caption and the key of the ids present.
Image category_row(const pgm::PolarGridMap& m, const char* channel, int scale, const std::string& (*name)(int)) {
  const float *values = m.channel(channel), *mask = m.channel("mask");
  const TextStyle style;
  const int s = style.scale;
  Image row = add_caption_band(scale_rows(category_image(values, mask, m.cols(), m.rows()), scale), channel, style);
  draw_legend_row(row, caption_end(channel, s), band_pad(s), category_key(values, mask, m.cells(), name),
                  row.width - band_pad(s), style);
  return row;
}

}  // namespace

Image pgm_image(const SimFrame& f) {
  const auto& m = f.pgm;
  const int rows = m.rows(), cols = m.cols();
  const float* mask = m.channel("mask");
  std::vector<std::uint8_t> valid(m.cells());
  for (std::size_t i = 0; i < m.cells(); ++i) valid[i] = mask[i] > 0;
  const float max_range = std::max(1.f, *std::max_element(m.channel("range"), m.channel("range") + m.cells()));
  const int scale = std::max(1, 128 / std::max(1, rows));
  const TextStyle style;
  char hi[32], header[96];
  std::snprintf(hi, sizeof hi, "%.0f", max_range);
  std::snprintf(header, sizeof header, "PGM channels, frame %d  t = %.1f s  (black: no return)", f.index, f.time);
  const Image stacked = stack_vertically(
      {add_caption_band(scale_rows(field_to_image(m.channel("range"), valid.data(), cols, rows, 0.f, max_range), scale),
                        "range (m)", ColourKey{"0", hi}, style),
       category_row(m, "class", scale, pgm::class_name), category_row(m, "material", scale, pgm::material_name),
       add_caption_band(scale_rows(field_to_image(m.channel("intensity"), valid.data(), cols, rows, 0.f, 1.f), scale),
                        "predicted intensity", ColourKey{"0", "1"}, style)},
      4);
  return add_caption_band(stacked, header, kHeaderStyle);
}

namespace {

// Bird's-eye view of the sensor frame: x forward is up, y left is left.
struct Bev {
  Image img;
  double res;   // m per pixel
  double x_lo;  // x at the bottom row
  double y_hi;  // y at the left column
  Bev(double range) : img(800, 800, kBevBackground), res(2 * range / 800), x_lo(-range), y_hi(range) {}
  bool px(double x, double y, int& u, int& v) const {
    u = static_cast<int>(std::floor((y_hi - y) / res));
    v = img.height - 1 - static_cast<int>(std::floor((x - x_lo) / res));
    return u >= 0 && u < img.width && v >= 0 && v < img.height;
  }
  void dot(double x, double y, Rgb c) {
    int u, v;
    if (px(x, y, u, v)) img.at(u, v) = c;
  }
  void line(double x0, double y0, double x1, double y1, Rgb c) {
    const double len = std::hypot(x1 - x0, y1 - y0);
    const int n = std::max(1, static_cast<int>(std::ceil(len / (0.5 * res))));
    for (int i = 0; i <= n; ++i) {
      const double t = static_cast<double>(i) / n;
      dot(x0 + t * (x1 - x0), y0 + t * (y1 - y0), c);
    }
  }
  void box(const sensor::Object& o, Rgb c) {
    // Footprint corners in order around the box (yaw-only boxes).
    const double ch = std::cos(o.heading), sh = std::sin(o.heading);
    const double hl = 0.5 * o.size.x(), hw = 0.5 * o.size.y();
    const double sx[4] = {hl, -hl, -hl, hl}, sy[4] = {hw, hw, -hw, -hw};
    double px[4], py[4];
    for (int i = 0; i < 4; ++i) {
      px[i] = o.position.x() + ch * sx[i] - sh * sy[i];
      py[i] = o.position.y() + sh * sx[i] + ch * sy[i];
    }
    for (int i = 0; i < 4; ++i) line(px[i], py[i], px[(i + 1) % 4], py[(i + 1) % 4], c);
    const Eigen::Vector2d c0(o.position.x(), o.position.y());
    // Heading tick from the centre to the front face.
    const double hx = std::cos(o.heading) * 0.5 * o.size.x(), hy = std::sin(o.heading) * 0.5 * o.size.x();
    line(c0.x(), c0.y(), c0.x() + hx, c0.y() + hy, c);
  }
};

Bev draw_bev(const SimFrame& f, double range) {
  Bev b(range);
  for (std::size_t i = 0; i < f.cloud.size(); ++i) b.dot(f.cloud.x[i], f.cloud.y[i], kBevPoint);
  for (const auto& l : f.lanes) {
    double px = l.x_min, py = sensor::evaluate(l, px);
    for (double x = l.x_min + 0.5; x <= l.x_max + 1e-9; x += 0.5) {
      const double y = sensor::evaluate(l, x);
      b.line(px, py, x, y, kBevLane);
      px = x;
      py = y;
    }
  }
  for (const auto& o : f.sensor.objects) b.box(o, o.visible_fraction > 0 ? kBevTruth : kBevTruthOccluded);
  for (const auto& r : f.reported)
    b.box(r.object, r.truth_id < 0 ? kBevFalsePositive : r.coasting ? kBevCoasting : kBevReported);
  // The sensor: a small cross at the origin.
  b.line(-1, 0, 1, 0, kBevSensor);
  b.line(0, -1, 0, 1, kBevSensor);
  return b;
}

// One entry per kind of mark draw_bev makes, in its colours.
std::vector<LegendEntry> bev_legend() {
  return {{"ground truth", kBevTruth},
          {"truth, occluded", kBevTruthOccluded},
          {"reported", kBevReported},
          {"coasting", kBevCoasting},
          {"false positive", kBevFalsePositive},
          {"lane", kBevLane, Mark::line},
          {"points", kBevPoint, Mark::marker},
          {"sensor", kBevSensor, Mark::marker}};
}

// The panel right of the map: legend at the top, orientation below it, scale bar at the bottom.
void draw_bev_panel(Image& img, int x0, int y0, double metres_per_pixel) {
  const int s = kBevText.scale, m = 6 * s;
  const auto legend = bev_legend();
  draw_legend_box(img, x0 + m, y0 + m, legend, kBevText);
  const int note_y = y0 + m + legend_box_height(legend, s) + 2 * m;
  draw_text(img, x0 + m, note_y, "sensor frame:", kBevText.ink, s);
  draw_text(img, x0 + m, note_y + kLineHeight * s, "x forward = up", kBevText.ink, s);
  draw_text(img, x0 + m, note_y + 2 * kLineHeight * s, "y left = left", kBevText.ink, s);
  const double metres = round_down_nice((img.width - x0 - 2 * m) * metres_per_pixel);
  char label[32];
  std::snprintf(label, sizeof label, "%g m", metres);
  const int length = static_cast<int>(std::lround(metres / metres_per_pixel));
  draw_scale_bar(img, x0 + m, img.height - m - scale_bar_height(s), length, label, kBevText);
}

}  // namespace

Image bev_image(const SimFrame& f, double range) {
  const Bev b = draw_bev(f, range);
  const int s = kBevText.scale, panel = legend_box_width(bev_legend(), s) + 2 * 6 * s;
  Image img = add_margins(b.img, 0, band_height(s), panel, 0, kBevBackground);
  // Thin rules keep the text apart from the map without covering any of it.
  fill_rect(img, 0, band_height(s) - 1, img.width, band_height(s), kBevRule);
  fill_rect(img, b.img.width, band_height(s), b.img.width + 1, img.height, kBevRule);
  char header[64];
  std::snprintf(header, sizeof header, "bird's-eye view, frame %d  t = %.1f s", f.index, f.time);
  draw_text(img, band_pad(s), band_pad(s), header, kBevText.ink, s);
  draw_bev_panel(img, b.img.width + 1, band_height(s), b.res);
  return img;
}

double percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const double pos = std::clamp(p, 0.0, 1.0) * (v.size() - 1);
  const std::size_t i = static_cast<std::size_t>(pos);
  if (i + 1 >= v.size()) return v.back();
  return v[i] + (pos - i) * (v[i + 1] - v[i]);
}

double write_frame_outputs(const SimOutputOptions& o, const SimFrame& f) {
  const auto t0 = std::chrono::steady_clock::now();
  if (o.format != "pcd" && o.format != "ply") throw Error("lidar-infer sim: --format must be pcd or ply, got " + o.format);
  if (f.intensity_skipped)
    throw Error("sim outputs: frame " + std::to_string(f.index) + " was run without its intensity (run_frame(k, frame, false))");

  // Objects: CSV and JSON.
  std::string csv = "source,id,truth_id,class,x,y,z,l,w,h,heading_deg,vx,vy,visible_fraction,score,coasting\n";
  nlohmann::json oj;
  oj["frame"] = f.index;
  oj["time"] = f.time;
  oj["frame_of_reference"] = "sensor";
  oj["reported"] = nlohmann::json::array();
  oj["ground_truth"] = nlohmann::json::array();
  for (const auto& r : f.reported) {
    csv_row(csv, "reported", r.object, r.truth_id, r.coasting);
    oj["reported"].push_back(object_json(r.object, r.truth_id, "coasting", r.coasting));
  }
  for (const auto& g : f.sensor.objects) {
    csv_row(csv, "truth", g, g.id, false);
    oj["ground_truth"].push_back(object_json(g, g.id));
  }
  write_file_atomically(o.out / frame_name("objects", f.index, "csv"), csv);
  write_file_atomically(o.out / frame_name("objects", f.index, "json"), oj.dump(1) + "\n");

  nlohmann::json lj;
  lj["frame"] = f.index;
  lj["time"] = f.time;
  lj["frame_of_reference"] = "sensor";
  lj["model"] = "y = c0 + c1 x + c2 x^2 + c3 x^3 on [x_min, x_max]";
  lj["lanes"] = nlohmann::json::array();
  for (const auto& l : f.lanes)
    lj["lanes"].push_back({{"id", l.id}, {"type", lane_type_name(l.type)}, {"c0", l.c0}, {"c1", l.c1}, {"c2", l.c2},
                           {"c3", l.c3}, {"x_min", l.x_min}, {"x_max", l.x_max}});
  write_file_atomically(o.out / frame_name("lanes", f.index, "json"), lj.dump(1) + "\n");

  data::PointCloud cloud;
  cloud.add_field("x", f.cloud.x);
  cloud.add_field("y", f.cloud.y);
  cloud.add_field("z", f.cloud.z);
  cloud.add_field("intensity", f.cloud.intensity);
  cloud.add_field("class", f.cloud.cls);
  cloud.add_field("material", f.cloud.material);
  cloud.add_field("object_id", f.cloud.object_id);
  cloud.add_field("range", f.cloud.range);
  data::write_point_cloud(o.out / frame_name("cloud", f.index, o.format.c_str()), cloud);

  if (o.images) {
    write_png(o.out / frame_name("pgm", f.index, "png"), pgm_image(f));
    double range = 0;
    for (float r : f.cloud.range) range = std::max<double>(range, r);
    write_png(o.out / frame_name("bev", f.index, "png"), bev_image(f, std::clamp(std::ceil(range / 10) * 10, 20.0, 120.0)));
  }
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

void SimStats::add(const SimFrame& f, double output_ms) {
  for (int s = 0; s < kNumSimStages; ++s) stage_ms_[s].push_back(f.stage_ms[s]);
  total_ms_.push_back(f.total_ms);
  output_ms_.push_back(output_ms);
  existing_ += f.objects_existing;
  in_view_ += f.objects_in_view;
  occluded_ += f.objects_occluded;
  partly_occluded_ += f.objects_partly_occluded;
  for (const auto& r : f.reported) {
    ++reported_;
    if (r.truth_id < 0) ++false_positives_;
  }
  points_ += static_cast<long>(f.cloud.size());
  lanes_ += static_cast<long>(f.lanes.size());
  intensity_skipped_ += f.intensity_skipped;
}

double SimStats::mean_ms(int s) const {
  const auto& v = stage_ms_[s];
  double sum = 0;
  for (double x : v) sum += x;
  return v.empty() ? 0 : sum / v.size();
}
double SimStats::p95_ms(int s) const { return percentile(stage_ms_[s], 0.95); }
double SimStats::mean_total_ms() const { return total_ms_.empty() ? 0 : compute_seconds() * 1000 / total_ms_.size(); }
double SimStats::p95_total_ms() const { return percentile(total_ms_, 0.95); }
double SimStats::compute_seconds() const {
  double sum = 0;
  for (double x : total_ms_) sum += x;
  return sum / 1000;
}
double SimStats::real_time_factor(double rate_hz) const {
  const double c = compute_seconds();
  return c > 0 ? frames() / rate_hz / c : 0;
}

SimStats::OutputTimes SimStats::output_times() const {
  OutputTimes o;
  std::vector<double> ms = writer_ms_;
  if (ms.empty()) {
    o.where = "pipeline thread";
    for (double x : output_ms_)
      if (x > 0) ms.push_back(x);
  } else {
    o.where = "writer thread";
  }
  o.frames = static_cast<int>(ms.size());
  if (ms.empty()) return o;
  double sum = 0;
  for (double x : ms) sum += x;
  o.mean = sum / ms.size();
  o.p95 = percentile(ms, 0.95);
  return o;
}

std::string SimStats::to_json(const Info& info) const {
  const double n = std::max(1, frames());
  nlohmann::json j;
  j["scenario"] = info.scenario;
  j["kpi_model"] = info.kpi_model;
  j["intensity_model"] = info.intensity_model;
  j["seed"] = info.seed;
  j["threads"] = info.threads;
  j["frames"] = frames();
  j["rate_hz"] = info.rate_hz;
  j["scenario_seconds"] = frames() / info.rate_hz;
  j["compute_seconds"] = compute_seconds();
  j["real_time_factor"] = real_time_factor(info.rate_hz);
  j["ms_per_frame"] = {{"mean", mean_total_ms()}, {"p95", p95_total_ms()}, {"note", "all stages, output writing excluded"}};
  for (int s = 0; s < kNumSimStages; ++s)
    j["stages_ms"][to_string(static_cast<SimStage>(s))] = {{"mean", mean_ms(s)}, {"p95", p95_ms(s)}};
  j["frames_without_intensity"] = intensity_skipped_;  // UNet skipped: outputs not written (--every)
  if (info.outputs) {
    const OutputTimes o = output_times();
    j["output_ms_per_written_frame"] = {{"mean", o.mean}, {"p95", o.p95}, {"frames_written", o.frames},
                                        {"thread", o.where}, {"note", "not in ms_per_frame"}};
    j["format"] = info.format;
  }
  j["wall_seconds"] = info.wall_seconds;
  j["per_frame_mean"] = {{"objects_existing", existing_ / n},
                         {"objects_in_view", in_view_ / n},
                         {"objects_occluded", occluded_ / n},
                         {"objects_partly_occluded", partly_occluded_ / n},
                         {"objects_reported", reported_ / n},
                         {"false_positives", false_positives_ / n},
                         {"lanes", lanes_ / n},
                         {"points", points_ / n}};
  return j.dump(2) + "\n";
}

std::string SimStats::to_markdown(const Info& info) const {
  const double n = std::max(1, frames());
  char line[512];
  std::string md = "# Simulation run\n\n";
  md += "Scenario `" + info.scenario + "`, KPI model `" + info.kpi_model + "`, intensity model `" +
        info.intensity_model + "`.\n\n";
  std::snprintf(line, sizeof line,
                "%d frames (%.1f s of scenario at %.0f Hz) on %d thread(s): %.2f ms per frame (p95 %.2f ms), "
                "**real-time factor %.2f** (scenario seconds / compute seconds; output writing excluded).\n\n",
                frames(), frames() / info.rate_hz, info.rate_hz, info.threads, mean_total_ms(), p95_total_ms(),
                real_time_factor(info.rate_hz));
  md += line;
  md += "| stage | mean ms | p95 ms |\n|---|---:|---:|\n";
  for (int s = 0; s < kNumSimStages; ++s) {
    std::snprintf(line, sizeof line, "| %s | %.3f | %.3f |\n", to_string(static_cast<SimStage>(s)), mean_ms(s), p95_ms(s));
    md += line;
  }
  std::snprintf(line, sizeof line, "| **total** | **%.3f** | **%.3f** |\n", mean_total_ms(), p95_total_ms());
  md += line;
  if (info.outputs) {
    // Not a pipeline stage: on the writer thread it runs beside the next frames; on the
    // pipeline's thread (--sync-outputs) it delays them. Either way it is per written frame.
    const OutputTimes o = output_times();
    std::snprintf(line, sizeof line, "| writing the outputs of a written frame (%s, %d frames; not in total) | %.3f | %.3f |\n",
                  o.where, o.frames, o.mean, o.p95);
    md += line;
  }
  if (intensity_skipped_ > 0) {
    std::snprintf(line, sizeof line,
                  "\nThe UNet ran on the %d frames whose outputs were written and was skipped on the other %d (its "
                  "intensity is read by the outputs only): its mean above is over all frames.\n",
                  frames() - intensity_skipped_, intensity_skipped_);
    md += line;
  }
  md += "\nPer frame (mean):\n\n| quantity | value |\n|---|---:|\n";
  const std::pair<const char*, double> rows[] = {{"objects in the scene", existing_ / n},
                                                 {"objects in view (FoV)", in_view_ / n},
                                                 {"fully occluded", occluded_ / n},
                                                 {"partly occluded", partly_occluded_ / n},
                                                 {"objects reported", reported_ / n},
                                                 {"of which false positives", false_positives_ / n},
                                                 {"lane polynomials", lanes_ / n},
                                                 {"points", points_ / n}};
  for (const auto& [name, v] : rows) {
    std::snprintf(line, sizeof line, "| %s | %.1f |\n", name, v);
    md += line;
  }
  if (info.outputs) {
    md += "\nFiles per frame NNNN: `objects_NNNN.csv|json` (reported list and ground truth, sensor frame), "
          "`lanes_NNNN.json` (cubic polynomials), `cloud_NNNN." + info.format +
          "` (x y z intensity class material object_id range), `pgm_NNNN.png` (PGM channels) and `bev_NNNN.png` "
          "(bird's-eye view), each with its legend.\n\n";
    if (frames() > 0 && info.images) {
      const int last = frames() - 1, mid = last / 2;
      md += "![bird's-eye view, frame " + std::to_string(mid) + "](" + frame_name("bev", mid, "png") + ")\n\n";
      md += "![PGM channels, frame " + std::to_string(mid) + "](" + frame_name("pgm", mid, "png") + ")\n";
    }
  }
  return md;
}

void SimStats::write_summary(const std::filesystem::path& out, const Info& info) const {
  write_file_atomically(out / "summary.json", to_json(info));
  write_file_atomically(out / "summary.md", to_markdown(info));
}

}  // namespace lidarsim::infer
