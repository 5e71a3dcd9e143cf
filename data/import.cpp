#include "data/import.h"

#include <algorithm>

#include "common/error.h"
#include "data/kitti_object.h"
#include "data/semantickitti.h"

namespace lidarsim::data {
namespace {

Dataset empty_dataset(const ImportOptions& options, const std::string& format) {
  if (options.first < 0 || options.max_frames < 0)
    throw Error("import: --first and --max-frames must be >= 0, got " + std::to_string(options.first) + " and " +
                std::to_string(options.max_frames));
  if (options.columns < 16 || options.columns % 16 != 0)
    throw Error("import: columns: must be a positive multiple of 16 (the validation split cuts 16 sectors), got " +
                std::to_string(options.columns));
  Dataset d;
  d.channels = dataset_channels(options);
  d.layout = pgm::BeamLayout::hdl64e(options.columns);
  d.source_format = format;
  return d;
}

template <typename T>
std::vector<T> window(const std::vector<T>& all, const ImportOptions& o) {
  const std::size_t first = std::min<std::size_t>(std::max(o.first, 0), all.size());
  std::size_t last = all.size();
  if (o.max_frames > 0) last = std::min(last, first + static_cast<std::size_t>(o.max_frames));
  return std::vector<T>(all.begin() + first, all.begin() + last);
}

void add_frame(Dataset& d, const std::vector<pgm::Point>& points, const ImportOptions& o, const std::string& id,
               const std::string& source) {
  pgm::ProjectOptions po;
  po.row_mode = o.row_mode;
  po.extra_channels = o.extra_channels;
  po.min_range = o.min_range;
  const auto result = pgm::project(points, d.layout, po, source);
  d.append(result.pgm, id, pgm::to_string(result.row_mode));
}

// Reads one listed scan; with skip_unreadable an unreadable one is noted and counted instead.
template <typename Read>
bool read_or_skip(const ImportOptions& o, int& skipped, Read&& read) {
  try {
    read();
    return true;
  } catch (const Error& e) {
    if (!o.skip_unreadable) throw;
    ++skipped;
    if (o.note) o.note(std::string("skipped unreadable scan: ") + e.what());
    return false;
  }
}

void note_counts(const ImportOptions& o, std::size_t found, int read, int unlabelled, int unreadable) {
  if (!o.note) return;
  std::string why;
  if (unlabelled) why += std::to_string(unlabelled) + " without labels";
  if (unreadable) why += std::string(why.empty() ? "" : ", ") + std::to_string(unreadable) + " unreadable";
  const std::size_t skipped = static_cast<std::size_t>(unlabelled + unreadable);
  o.note("found " + std::to_string(found) + " scans, read " + std::to_string(read) + ", skipped " +
         std::to_string(skipped) + (why.empty() ? "" : " (" + why + ")") +
         (found > static_cast<std::size_t>(read) + skipped ? "; the rest outside --first/--max-frames" : ""));
}

}  // namespace

std::vector<std::string> dataset_channels(const ImportOptions& options) {
  std::vector<std::string> c = {"range", "class", "material"};
  for (const auto& e : options.extra_channels) {
    if (std::find(pgm::kEffectChannels.begin(), pgm::kEffectChannels.end(), e) == pgm::kEffectChannels.end())
    {
      std::string known;
      for (const auto& k : pgm::kEffectChannels) known += (known.empty() ? "" : ", ") + k;
      throw Error("import: channel '" + e + "': unknown (known: " + known + ")");
    }
    if (std::find(c.begin(), c.end(), e) == c.end()) c.push_back(e);
  }
  return c;
}

Dataset import_semantickitti(const std::filesystem::path& dir, const ImportOptions& options) {
  Dataset d = empty_dataset(options, "semantickitti");
  std::vector<ScanFiles> scans;
  int unlabelled = 0, unreadable = 0;
  const auto listed = list_semantickitti(dir, options.sequences);
  for (const auto& s : listed) {
    if (s.label || options.include_unlabelled) scans.push_back(s);
    else ++unlabelled;
  }
  if (unlabelled && options.note)
    options.note("skipped " + std::to_string(unlabelled) + " scans without labels (--include-unlabelled reads them)");
  scans = window(scans, options);
  if (scans.empty())
    throw input_error(dir.string(), "scans", options.include_unlabelled ? "no velodyne/*.bin scans found"
                                                                         : "no labelled scans (velodyne/*.bin with labels/*.label) found");
  for (std::size_t i = 0; i < scans.size(); ++i) {
    LabelledScan scan;
    if (!read_or_skip(options, unreadable, [&] { scan = read_semantickitti_scan(scans[i]); })) continue;
    if (scan.unknown_labels && options.note)
      options.note(scans[i].label->string() + ": " + std::to_string(scan.unknown_labels) +
                   " labels outside the SemanticKITTI classes, imported as unlabeled");
    add_frame(d, scan.points, options, "semantickitti/" + scans[i].sequence + "/" + scans[i].id, scans[i].bin.string());
    for (const auto& s : scan.sources) d.sources.push_back(s.string());
    if (options.progress) options.progress(static_cast<int>(i + 1), static_cast<int>(scans.size()));
  }
  note_counts(options, listed.size(), d.size(), unlabelled, unreadable);
  if (d.size() == 0) throw input_error(dir.string(), "scans", "none of the listed scans could be read");
  return d;
}

Dataset import_kitti_object(const std::filesystem::path& dir, const ImportOptions& options) {
  Dataset d = empty_dataset(options, "kitti_object");
  const auto listed = list_kitti_object(dir);
  const auto frames = window(listed, options);
  if (frames.empty()) throw input_error(dir.string(), "frames", "no velodyne/*.bin frames found");
  int unreadable = 0;
  for (std::size_t i = 0; i < frames.size(); ++i) {
    KittiObjectScan scan;
    if (!read_or_skip(options, unreadable, [&] { scan = read_kitti_object_scan(frames[i]); })) continue;
    add_frame(d, scan.points, options, "kitti_object/" + frames[i].id, frames[i].bin.string());
    for (const auto& s : scan.sources) d.sources.push_back(s.string());
    if (options.progress) options.progress(static_cast<int>(i + 1), static_cast<int>(frames.size()));
  }
  note_counts(options, listed.size(), d.size(), 0, unreadable);
  if (d.size() == 0) throw input_error(dir.string(), "frames", "none of the listed frames could be read");
  return d;
}

}  // namespace lidarsim::data
