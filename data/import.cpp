#include "data/import.h"

#include <omp.h>

#include <algorithm>
#include <exception>
#include <memory>

#include "common/error.h"
#include "data/dataset_writer.h"
#include "data/class_table.h"
#include "data/kitti_object.h"
#include "data/nuscenes.h"
#include "data/nuscenes_lidarseg.h"
#include "data/ouster.h"
#include "data/rellis3d.h"
#include "data/semantickitti.h"
#include "data/semantickitti_mos.h"
#include "pgm/materials.h"

namespace lidarsim::data {
namespace fs = std::filesystem;
namespace {

// One scan as its reader returns it.
struct RecordedScan {
  RecordedScan() = default;
  RecordedScan(std::vector<pgm::Point> p, std::vector<fs::path> s, IntensityScale sc)
      : points(std::move(p)), sources(std::move(s)), scale(std::move(sc)) {}
  std::vector<pgm::Point> points;
  std::vector<fs::path> sources;
  std::string note;  // for the user (unknown labels, ...), empty when nothing to say
  IntensityScale scale;
  std::size_t dropped = 0;                       // points of the file the reader left out
  std::map<std::string, std::size_t> unmapped;   // foreign class -> points imported as unlabeled
  std::vector<std::int64_t> file_index;          // per point, its index in the file (empty: the same)
  std::vector<float> motion;                     // per point, the "motion" channel's value (or empty)
};

// What the summary counts of one scan, taken before its points are freed.
struct ScanCounts {
  long long points = 0, dropped = 0;
  std::vector<long long> classes;  // points per class id
  std::map<std::string, std::size_t> unmapped;
  std::vector<long long> motion;   // points per Motion value (empty without the channel)
};

// One scan to import: its ids and how to read it (called on any thread).
struct ScanJob {
  std::string id;  // frame id in /frames
  FramePlace place;
  std::string path;  // named in projection errors
  std::function<RecordedScan()> read;
};

struct ProjectedScan {
  pgm::PolarGridMap pgm;
  std::string row_mode;
  std::vector<fs::path> sources;
  std::string note;
  bool skipped = false;  // unreadable, and the user asked to skip such scans
  IntensityScale scale;
  ScanCounts counts;
};

// How many scans the listing found, and how many it left out for want of labels.
struct ListCounts {
  std::size_t found = 0;
  int unlabelled = 0;
};

void note_counts(const ImportOptions& o, const ListCounts& c, int read, int unreadable) {
  if (!o.note) return;
  std::string why;
  if (c.unlabelled) why += std::to_string(c.unlabelled) + " without labels";
  if (unreadable) why += std::string(why.empty() ? "" : ", ") + std::to_string(unreadable) + " unreadable";
  const std::size_t skipped = static_cast<std::size_t>(c.unlabelled + unreadable);
  o.note("found " + std::to_string(c.found) + " scans, read " + std::to_string(read) + ", skipped " +
         std::to_string(skipped) + (why.empty() ? "" : " (" + why + ")") +
         (c.found > static_cast<std::size_t>(read) + skipped ? "; the rest outside --first/--max-frames" : ""));
}

template <typename T>
std::vector<T> window(const std::vector<T>& all, const ImportOptions& o) {
  const std::size_t first = std::min<std::size_t>(std::max(o.first, 0), all.size());
  std::size_t last = all.size();
  if (o.max_frames > 0) last = std::min(last, first + static_cast<std::size_t>(o.max_frames));
  return std::vector<T>(all.begin() + first, all.begin() + last);
}

void check_columns(int columns) {
  if (columns < 16 || columns % 16 != 0)
    throw Error("import: columns: must be a positive multiple of 16 (the validation split cuts 16 sectors), got " +
                std::to_string(columns));
}

std::vector<ScanJob> semantickitti_jobs(const fs::path& dir, const ImportOptions& options, ListCounts& counts) {
  std::vector<ScanFiles> scans;
  int unlabelled = 0;
  const auto listed = list_semantickitti(dir, options.sequences);
  for (const auto& s : listed) {
    if (s.label || options.include_unlabelled) scans.push_back(s);
    else ++unlabelled;
  }
  counts = {listed.size(), unlabelled};
  if (unlabelled && options.note)
    options.note("skipped " + std::to_string(unlabelled) + " scans without labels (--include-unlabelled reads them)");
  scans = window(scans, options);
  if (scans.empty())
    throw input_error(dir.string(), "scans", options.include_unlabelled ? "no velodyne/*.bin scans found"
                                                                         : "no labelled scans (velodyne/*.bin with labels/*.label) found");
  std::vector<ScanJob> jobs;
  for (const auto& s : scans) {
    jobs.push_back({"semantickitti/" + s.sequence + "/" + s.id, {"semantickitti", s.sequence, s.id}, s.bin.string(), [s] {
                      LabelledScan scan = read_semantickitti_scan(s);
                      RecordedScan r{std::move(scan.points), std::move(scan.sources), intensity_scale_of(SourceFormat::SemanticKitti)};
                      if (scan.unknown_labels)
                        r.note = s.label->string() + ": " + std::to_string(scan.unknown_labels) +
                                 " labels outside the SemanticKITTI classes, imported as unlabeled";
                      return r;
                    }});
  }
  return jobs;
}

std::vector<ScanJob> kitti_object_jobs(const fs::path& dir, const ImportOptions& options, ListCounts& counts) {
  const auto listed = list_kitti_object(dir);
  counts.found = listed.size();
  const auto frames = window(listed, options);
  if (frames.empty()) throw input_error(dir.string(), "frames", "no velodyne/*.bin frames found");
  std::vector<ScanJob> jobs;
  // KITTI object frames do not say which drive they come from: each frame is its own place.
  for (const auto& f : frames)
    jobs.push_back({"kitti_object/" + f.id, {"kitti_object", "", f.id}, f.bin.string(), [f] {
                      KittiObjectScan scan = read_kitti_object_scan(f);
                      return RecordedScan{std::move(scan.points), std::move(scan.sources), intensity_scale_of(SourceFormat::KittiObject)};
                    }});
  return jobs;
}

std::vector<ScanJob> nuscenes_jobs(const fs::path& dir, const ImportOptions& options, ListCounts& counts) {
  const auto listed = list_nuscenes(dir);
  counts.found = listed.size();
  const auto files = window(listed, options);
  if (files.empty()) throw input_error(dir.string(), "sweeps", "no *.pcd.bin files found");
  std::vector<ScanJob> jobs;
  for (const auto& f : files) {
    const std::string log = f.log.empty() ? "-" : f.log;
    jobs.push_back({"nuscenes/" + log + "/" + f.timestamp, {"nuscenes", f.log, f.timestamp}, f.path.string(), [f] {
                      return RecordedScan{read_nuscenes_pcd_bin(f.path), {f.path}, intensity_scale_of(SourceFormat::Nuscenes)};
                    }});
  }
  return jobs;
}

// The options' class table (read once, shared by the jobs).
std::shared_ptr<const ClassTable> class_table_for(SourceFormat format, const ImportOptions& options, const char* bundled) {
  if (options.classes) return options.classes;
  if (options.class_table.empty())
    throw Error("import: " + to_string(format) + " needs a class table (" + bundled + ", --classes)");
  return std::make_shared<const ClassTable>(read_class_table(options.class_table));
}

std::vector<ScanJob> rellis3d_jobs(const fs::path& dir, const ImportOptions& options, ListCounts& counts) {
  auto table = class_table_for(SourceFormat::Rellis3d, options, "data/ontologies/rellis3d.csv");
  const auto listed = list_rellis3d(dir);
  counts.found = listed.size();
  const auto files = window(listed, options);
  std::vector<ScanJob> jobs;
  for (const auto& f : files) {
    jobs.push_back({"rellis3d/" + f.sequence + "/" + f.id, {"rellis3d", f.sequence, f.id}, f.bin.string(), [f, table] {
                      Rellis3dScan scan = read_rellis3d_scan(f, *table);
                      RecordedScan r{std::move(scan.points), std::move(scan.sources),
                                     scan.reflectivity ? intensity_scale_of(SourceFormat::Rellis3d) : intensity_scale::rellis3d_bin()};
                      r.unmapped = scan.unmapped;
                      std::string unmapped;
                      for (const auto& [name, n] : scan.unmapped)
                        unmapped += (unmapped.empty() ? "" : ", ") + name + " " + std::to_string(n);
                      if (!unmapped.empty())
                        r.note = f.bin.string() + ": points of RELLIS classes without a class of ours, imported as "
                                 "unlabeled: " + unmapped;
                      if (!f.ply)
                        r.note += std::string(r.note.empty() ? "" : "; ") + f.bin.string() +
                                  ": no PLY beside it, intensity is the .bin's rescaled value";
                      return r;
                    }});
  }
  return jobs;
}

std::vector<fs::path> ouster_pcaps(const fs::path& dir) {
  std::error_code ec;
  if (fs::is_regular_file(dir, ec)) return {dir};
  if (!fs::is_directory(dir, ec)) throw input_error(dir.string(), "pcap", "not found");
  std::vector<fs::path> pcaps;
  for (const auto& e : fs::directory_iterator(dir))
    if (e.is_regular_file() && e.path().extension() == ".pcap") pcaps.push_back(e.path());
  std::sort(pcaps.begin(), pcaps.end());
  if (pcaps.empty()) throw input_error(dir.string(), "pcaps", "no .pcap files found");
  return pcaps;
}

std::vector<ScanJob> ouster_jobs(const fs::path& dir, const ImportOptions& options, ListCounts& counts) {
  std::vector<ScanJob> jobs;
  for (const auto& pcap : ouster_pcaps(dir)) {
    auto meta = std::make_shared<const OusterMetadata>(
        read_ouster_metadata(options.ouster_metadata.empty() ? ouster_metadata_for(pcap) : options.ouster_metadata));
    // Decoded once here: packets of one frame are spread over the file.
    auto frames = std::make_shared<const std::vector<OusterFrame>>(read_ouster_pcap(pcap, *meta));
    const std::string recording = pcap.stem().string();
    for (std::size_t k = 0; k < frames->size(); ++k) {
      const std::string id = std::to_string((*frames)[k].frame_id);
      jobs.push_back({"ouster/" + recording + "/" + id, {"ouster", recording, id}, pcap.string(), [meta, frames, k, pcap] {
                        const OusterFrame& f = (*frames)[k];
                        RecordedScan r{ouster_points(f, *meta), {pcap, fs::path(meta->path)},
                                       intensity_scale_of(SourceFormat::Ouster)};
                        if (f.valid_columns() < f.cols)
                          r.note = pcap.string() + ": frame " + std::to_string(f.frame_id) + " has " +
                                   std::to_string(f.valid_columns()) + " of " + std::to_string(f.cols) + " columns";
                        return r;
                      }});
    }
  }
  counts.found = jobs.size();
  return window(jobs, options);
}

std::vector<ScanJob> nuscenes_lidarseg_jobs(const fs::path& dir, const ImportOptions& options, ListCounts& counts) {
  auto table = class_table_for(SourceFormat::NuscenesLidarseg, options, "data/ontologies/nuscenes-lidarseg.csv");
  const auto listed = list_nuscenes_lidarseg(dir);
  counts.found = listed.size();
  const auto files = window(listed, options);
  if (files.empty()) throw input_error(dir.string(), "scans", "none left after --first/--max-frames");
  // The folder is one scene: its name is the place (the copied frames do not record the scene's).
  const std::string scene = fs::weakly_canonical(dir).filename().string();
  std::vector<ScanJob> jobs;
  for (const auto& f : files)
    jobs.push_back({"nuscenes/" + scene + "/" + f.id, {"nuscenes", scene, f.id}, f.pcd.string(), [f, table] {
                      NuscenesLidarsegScan scan = read_nuscenes_lidarseg_scan(f, *table);
                      RecordedScan r{std::move(scan.points), {f.pcd, f.labels}, intensity_scale_of(SourceFormat::NuscenesLidarseg)};
                      r.dropped = scan.ego;
                      r.unmapped = std::move(scan.unmapped);
                      r.file_index = std::move(scan.file_index);
                      return r;
                    }});
  return jobs;
}

std::vector<ScanJob> semantickitti_mos_jobs(const fs::path& dir, const ImportOptions& options, ListCounts& counts) {
  if (options.include_unlabelled)
    throw Error("import: semantickitti_mos: --include-unlabelled does not apply (a scan without its moving-object "
                "labels is plain SemanticKITTI: import it with --semantickitti)");
  std::vector<ScanFiles> scans;
  int unlabelled = 0;
  const auto listed = list_semantickitti_mos(dir, options.sequences);
  for (const auto& s : listed) {
    if (s.label) scans.push_back(s);
    else ++unlabelled;
  }
  counts = {listed.size(), unlabelled};
  if (unlabelled && options.note)
    options.note("skipped " + std::to_string(unlabelled) + " scans without a moving-object label file (labels_mos/ or labels/)");
  scans = window(scans, options);
  if (scans.empty())
    throw input_error(dir.string(), "scans", "no scans with moving-object labels (velodyne/*.bin with labels_mos/*.label) found");
  std::vector<ScanJob> jobs;
  for (const auto& s : scans)
    jobs.push_back({"semantickitti/" + s.sequence + "/" + s.id, {"semantickitti", s.sequence, s.id}, s.bin.string(), [s] {
                      MosScan scan = read_semantickitti_mos_scan(s);
                      RecordedScan r{std::move(scan.points), std::move(scan.sources), intensity_scale_of(SourceFormat::SemanticKittiMos)};
                      r.motion = std::move(scan.motion);
                      return r;
                    }});
  return jobs;
}

std::vector<ScanJob> list_jobs(SourceFormat format, const fs::path& dir, const ImportOptions& options, ListCounts& counts) {
  if (options.first < 0 || options.max_frames < 0)
    throw Error("import: --first and --max-frames must be >= 0, got " + std::to_string(options.first) + " and " +
                std::to_string(options.max_frames));
  switch (format) {
    case SourceFormat::SemanticKitti: return semantickitti_jobs(dir, options, counts);
    case SourceFormat::KittiObject: return kitti_object_jobs(dir, options, counts);
    case SourceFormat::Nuscenes: return nuscenes_jobs(dir, options, counts);
    case SourceFormat::Rellis3d: return rellis3d_jobs(dir, options, counts);
    case SourceFormat::Ouster: return ouster_jobs(dir, options, counts);
    case SourceFormat::NuscenesLidarseg: return nuscenes_lidarseg_jobs(dir, options, counts);
    case SourceFormat::SemanticKittiMos: return semantickitti_mos_jobs(dir, options, counts);
  }
  throw Error("import: unknown source format");
}

pgm::BeamLayout default_layout(SourceFormat format, const fs::path& dir, const ImportOptions& options) {
  if (options.layout) {
    options.layout->validate("import: beam layout");
    check_columns(options.layout->columns);
    return *options.layout;
  }
  check_columns(options.columns);
  switch (format) {
    case SourceFormat::SemanticKitti:
    case SourceFormat::SemanticKittiMos:
    case SourceFormat::KittiObject: return pgm::BeamLayout::hdl64e(options.columns);
    case SourceFormat::Ouster: {
      const fs::path pcap = ouster_pcaps(dir).front();
      auto layout = read_ouster_metadata(options.ouster_metadata.empty() ? ouster_metadata_for(pcap) : options.ouster_metadata).layout();
      check_columns(layout.columns);
      return layout;
    }
    case SourceFormat::Nuscenes:
    case SourceFormat::NuscenesLidarseg:
    case SourceFormat::Rellis3d:
      throw Error("import: " + to_string(format) + ": give the sensor's beam layout (--sensor data/sensors/...json)");
  }
  throw Error("import: unknown source format");
}

ScanCounts count_points(const RecordedScan& scan) {
  ScanCounts c;
  c.points = static_cast<long long>(scan.points.size() + scan.dropped);
  c.dropped = static_cast<long long>(scan.dropped);
  c.classes.assign(static_cast<std::size_t>(pgm::class_count()), 0);
  for (const auto& p : scan.points)
    if (p.class_id >= 0 && p.class_id < pgm::class_count()) ++c.classes[static_cast<std::size_t>(p.class_id)];
  c.unmapped = scan.unmapped;
  if (!scan.motion.empty()) {
    c.motion.assign(kMotionNames.size(), 0);
    for (float m : scan.motion) ++c.motion[static_cast<std::size_t>(m)];
  }
  return c;
}

// The reader's per-point extras carried into the grid: the "motion" channel from the point each
// cell holds (0 in empty cells: the mask tells them apart), and /point_index as the index in the
// file when the reader left points out.
void add_point_extras(const RecordedScan& scan, pgm::PolarGridMap& map) {
  auto& index = map.point_index();
  if (!scan.motion.empty()) {
    float* motion = map.channel(map.add_channel(kMotionChannel));
    for (std::size_t k = 0; k < map.cells(); ++k)
      if (index[k] >= 0) motion[k] = scan.motion[static_cast<std::size_t>(index[k])];
  }
  if (!scan.file_index.empty())
    for (auto& k : index)
      if (k >= 0) k = scan.file_index[static_cast<std::size_t>(k)];
}

// One scan's counts into the summary; one dataset holds one intensity scale.
void add_counts(ImportSummary& summary, const ScanJob& job, const ProjectedScan& scan) {
  if (!summary.intensity_scale.recorded()) summary.intensity_scale = scan.scale;
  else if (!(scan.scale == summary.intensity_scale))
    throw input_error(job.path, "intensity", "on the scale " + scan.scale.describe() + ", the scans before it on " +
                                                 summary.intensity_scale.describe() +
                                                 ": one dataset holds one scale (import them into separate files)");
  const ScanCounts& c = scan.counts;
  summary.points += c.points;
  summary.dropped_points += c.dropped;
  for (std::size_t k = 0; k < c.classes.size(); ++k)
    if (c.classes[k]) summary.classes[pgm::class_name(static_cast<int>(k))] += c.classes[k];
  for (const auto& [name, n] : c.unmapped) summary.unmapped[name] += static_cast<long long>(n);
  for (std::size_t k = 0; k < c.motion.size(); ++k) summary.motion[kMotionNames[k]] += c.motion[k];
}

// Reads and projects the jobs a block at a time in parallel and hands each frame, in order, to
// `sink`, counting it into `summary`. Errors are rethrown in job order, so the first bad file is
// the one reported; with skip_unreadable a scan whose reader fails is noted and skipped instead.
// Returns how many were.
template <typename Sink>
int run_jobs(const std::vector<ScanJob>& jobs, const pgm::BeamLayout& layout, const ImportOptions& o,
             ImportSummary& summary, Sink&& sink) {
  pgm::ProjectOptions po;
  po.row_mode = o.row_mode;
  po.extra_channels = o.extra_channels;
  po.min_range = o.min_range;
  const int block = o.block > 0 ? o.block : 4 * omp_get_max_threads();
  const int total = static_cast<int>(jobs.size());
  std::vector<ProjectedScan> done(block);
  std::vector<std::exception_ptr> errors(block);
  int skipped = 0;
  for (int start = 0; start < total; start += block) {
    const int count = std::min(block, total - start);
#pragma omp parallel for schedule(dynamic, 1)
    for (int i = 0; i < count; ++i) {
      try {
        const ScanJob& job = jobs[start + i];
        RecordedScan scan;
        try {
          scan = job.read();
        } catch (const Error& e) {
          if (!o.skip_unreadable) throw;
          done[i] = {};
          done[i].skipped = true;
          done[i].note = std::string("skipped unreadable scan: ") + e.what();
          continue;
        }
        auto result = pgm::project(scan.points, layout, po, job.path);
        add_point_extras(scan, result.pgm);
        done[i] = {std::move(result.pgm), pgm::to_string(result.row_mode), std::move(scan.sources), std::move(scan.note),
                   false, scan.scale, count_points(scan)};
      } catch (...) {
        errors[i] = std::current_exception();
      }
    }
    for (int i = 0; i < count; ++i) {
      if (errors[i]) std::rethrow_exception(errors[i]);
      if (!done[i].note.empty() && o.note) o.note(done[i].note);
      if (done[i].skipped) {
        ++skipped;
      } else {
        add_counts(summary, jobs[start + i], done[i]);
        sink(jobs[start + i], done[i]);
      }
      done[i] = {};  // frees the grid before the next block
      if (o.progress) o.progress(start + i + 1, total);
    }
  }
  return skipped;
}

// The summary note, and an error when no listed scan could be read.
void finish_counts(const fs::path& dir, const ImportOptions& o, const ListCounts& counts, int read, int skipped) {
  note_counts(o, counts, read, skipped);
  if (read == 0) throw input_error(dir.string(), "scans", "none of the listed scans could be read");
}

}  // namespace

std::string to_string(SourceFormat format) {
  switch (format) {
    case SourceFormat::SemanticKitti: return "semantickitti";
    case SourceFormat::KittiObject: return "kitti_object";
    case SourceFormat::Nuscenes: return "nuscenes";
    case SourceFormat::Rellis3d: return "rellis3d";
    case SourceFormat::Ouster: return "ouster";
    case SourceFormat::NuscenesLidarseg: return "nuscenes_lidarseg";
    case SourceFormat::SemanticKittiMos: return "semantickitti_mos";
  }
  return "unknown";
}

SourceFormat source_format_from_string(const std::string& name) {
  const SourceFormat all[] = {SourceFormat::SemanticKitti, SourceFormat::KittiObject,      SourceFormat::Nuscenes,
                              SourceFormat::Rellis3d,      SourceFormat::Ouster,           SourceFormat::NuscenesLidarseg,
                              SourceFormat::SemanticKittiMos};
  std::string known;
  for (SourceFormat f : all) {
    if (to_string(f) == name) return f;
    known += (known.empty() ? "" : ", ") + to_string(f);
  }
  throw Error("import: format '" + name + "': unknown (known: " + known + ")");
}

IntensityScale intensity_scale_of(SourceFormat format) {
  switch (format) {
    case SourceFormat::SemanticKitti:
    case SourceFormat::KittiObject:
    case SourceFormat::SemanticKittiMos: return intensity_scale::kitti_reflectance();
    case SourceFormat::Nuscenes:
    case SourceFormat::NuscenesLidarseg: return intensity_scale::nuscenes_intensity();
    case SourceFormat::Rellis3d: return intensity_scale::rellis3d_reflectivity();
    case SourceFormat::Ouster: return intensity_scale::ouster_reflectivity();
  }
  throw Error("import: unknown source format");
}

std::vector<std::string> dataset_channels(const ImportOptions& options) {
  std::vector<std::string> c = {"range", "class", "material"};
  for (const auto& e : options.extra_channels) {
    if (std::find(pgm::kEffectChannels.begin(), pgm::kEffectChannels.end(), e) == pgm::kEffectChannels.end()) {
      std::string known;
      for (const auto& k : pgm::kEffectChannels) known += (known.empty() ? "" : ", ") + k;
      throw Error("import: channel '" + e + "': unknown (known: " + known + ")");
    }
    if (std::find(c.begin(), c.end(), e) == c.end()) c.push_back(e);
  }
  return c;
}

std::vector<std::string> dataset_channels(SourceFormat format, const ImportOptions& options) {
  std::vector<std::string> c = dataset_channels(options);
  if (format == SourceFormat::SemanticKittiMos) c.push_back(kMotionChannel);
  return c;
}

ImportSummary import_to_file(SourceFormat format, const fs::path& dir, const fs::path& out, const ImportOptions& options) {
  ImportSummary summary;
  summary.layout = default_layout(format, dir, options);
  summary.channels = dataset_channels(format, options);
  ListCounts counts;
  const auto jobs = list_jobs(format, dir, options, counts);
  DatasetWriter writer(out, summary.channels, summary.layout, to_string(format));
  const int skipped = run_jobs(jobs, summary.layout, options, summary, [&](const ScanJob& job, const ProjectedScan& scan) {
    writer.append(scan.pgm, job.id, scan.row_mode, job.place);
    for (const auto& s : scan.sources) writer.add_source(s.string());
  });
  finish_counts(dir, options, counts, writer.size(), skipped);
  writer.set_intensity_scale(summary.intensity_scale);
  writer.commit();
  summary.frames = writer.size();
  summary.returns = writer.returns();
  summary.row_modes = writer.row_mode_counts();
  return summary;
}

Dataset import_dataset(SourceFormat format, const fs::path& dir, const ImportOptions& options, ImportSummary* summary) {
  Dataset d;
  d.layout = default_layout(format, dir, options);
  d.channels = dataset_channels(format, options);
  d.source_format = to_string(format);
  ListCounts counts;
  const auto jobs = list_jobs(format, dir, options, counts);
  ImportSummary s;
  const int skipped = run_jobs(jobs, d.layout, options, s, [&](const ScanJob& job, const ProjectedScan& scan) {
    d.append(scan.pgm, job.id, scan.row_mode, job.place);
    for (const auto& f : scan.sources) d.sources.push_back(f.string());
  });
  finish_counts(dir, options, counts, d.size(), skipped);
  d.intensity_scale = s.intensity_scale;
  if (summary) {
    s.frames = d.size();
    s.layout = d.layout;
    s.channels = d.channels;
    for (const auto& m : d.row_modes) ++s.row_modes[m];
    s.returns = 0;
    for (std::size_t k = 0; k < d.mask.numel(); ++k) s.returns += d.mask.data()[k] > 0;
    *summary = std::move(s);
  }
  return d;
}

Dataset import_semantickitti(const fs::path& dir, const ImportOptions& options) {
  return import_dataset(SourceFormat::SemanticKitti, dir, options);
}

Dataset import_kitti_object(const fs::path& dir, const ImportOptions& options) {
  return import_dataset(SourceFormat::KittiObject, dir, options);
}

}  // namespace lidarsim::data
