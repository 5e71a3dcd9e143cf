#include "data/ouster.h"

#include <pcap/pcap.h>

#include <cmath>
#include <cstring>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>
#include <numbers>

#include "common/angles.h"
#include "common/error.h"

namespace lidarsim::data {
namespace fs = std::filesystem;
namespace {


template <typename T>
T le(const std::uint8_t* p) {
  T v;
  std::memcpy(&v, p, sizeof(T));  // the packets are little-endian, as is every host we build on
  return v;
}

std::vector<double> numbers(const nlohmann::json& j, const std::string& fname, const char* key) {
  if (!j.contains(key) || !j[key].is_array()) throw input_error(fname, key, "missing or not an array");
  std::vector<double> out;
  for (const auto& v : j[key]) {
    if (!v.is_number()) throw input_error(fname, key, "expected numbers");
    out.push_back(v.get<double>());
  }
  return out;
}

struct Profile {
  bool legacy = false;
  int pixel_bytes = 12;
  int column_header = 12;
};

Profile profile_of(const OusterMetadata& m) {
  if (m.udp_profile_lidar == "LEGACY") return {true, 12, 16};
  if (m.udp_profile_lidar == "RNG19_RFL8_SIG16_NIR16") return {false, 12, 12};
  if (m.udp_profile_lidar == "RNG15_RFL8_NIR8") return {false, 4, 12};
  throw input_error(m.path, "data_format.udp_profile_lidar",
                    "'" + m.udp_profile_lidar + "' is not parsed (LEGACY, RNG19_RFL8_SIG16_NIR16, RNG15_RFL8_NIR8)");
}

}  // namespace

std::size_t OusterMetadata::packet_bytes() const {
  const Profile p = profile_of(*this);
  const std::size_t column = p.column_header + static_cast<std::size_t>(pixels_per_column) * p.pixel_bytes + (p.legacy ? 4 : 0);
  return (p.legacy ? 0 : 32 + 32) + column * columns_per_packet;
}

pgm::BeamLayout OusterMetadata::layout() const {
  pgm::BeamLayout l;
  l.name = prod_line.empty() ? "ouster" : prod_line;
  l.sensor = "Ouster " + prod_line + " " + firmware + " " + lidar_mode + " " + udp_profile_lidar + " (from " +
             fs::path(path).filename().string() + ")";
  l.columns = columns_per_frame;
  for (double a : beam_altitude_deg) l.elevations_rad.push_back(a * kDeg);
  for (double a : beam_azimuth_deg) l.azimuth_offsets_rad.push_back(-a * kDeg);
  l.validate(path + ": beam_altitude_angles");
  return l;
}

OusterMetadata read_ouster_metadata(const fs::path& path) {
  const std::string fname = path.string();
  std::ifstream in(path);
  if (!in) throw input_error(fname, "file", "not found or cannot be opened");
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(in);
  } catch (const nlohmann::json::exception& e) {
    throw input_error(fname, "file", std::string("not valid JSON: ") + e.what());
  }
  if (!j.is_object()) throw input_error(fname, "file", "not a JSON object");
  // Optional strings: absent is the default, another type an error naming the field (json's
  // value() would throw its own type_error, found by fuzz/ ouster_metadata).
  auto text = [&](const nlohmann::json& parent, const char* key, const std::string& field, std::string fallback) {
    if (!parent.contains(key)) return fallback;
    if (!parent[key].is_string()) throw input_error(fname, field, "not a string");
    return parent[key].get<std::string>();
  };
  OusterMetadata m;
  m.path = fname;
  m.prod_line = text(j, "prod_line", "prod_line", "");
  m.firmware = text(j, "build_rev", "build_rev", "");
  m.lidar_mode = text(j, "lidar_mode", "lidar_mode", "");
  if (!j.contains("data_format") || !j["data_format"].is_object()) throw input_error(fname, "data_format", "missing");
  const auto& f = j["data_format"];
  auto get_int = [&](const char* key) {
    if (!f.contains(key) || !f[key].is_number_integer()) throw input_error(fname, std::string("data_format.") + key, "missing or not an integer");
    const int v = f[key].get<int>();
    if (v <= 0) throw input_error(fname, std::string("data_format.") + key, "must be positive");
    return v;
  };
  m.columns_per_frame = get_int("columns_per_frame");
  m.columns_per_packet = get_int("columns_per_packet");
  m.pixels_per_column = get_int("pixels_per_column");
  m.udp_profile_lidar = text(f, "udp_profile_lidar", "data_format.udp_profile_lidar", "LEGACY");
  profile_of(m);  // refuses a profile we do not parse, naming the field
  if (j.contains("udp_port_lidar") && j["udp_port_lidar"].is_number_integer() && j["udp_port_lidar"].get<int>() > 0)
    m.udp_port_lidar = j["udp_port_lidar"].get<int>();
  m.beam_altitude_deg = numbers(j, fname, "beam_altitude_angles");
  m.beam_azimuth_deg = numbers(j, fname, "beam_azimuth_angles");
  for (const char* key : {"beam_altitude_angles", "beam_azimuth_angles"}) {
    const auto n = std::string(key) == "beam_altitude_angles" ? m.beam_altitude_deg.size() : m.beam_azimuth_deg.size();
    if (static_cast<int>(n) != m.pixels_per_column)
      throw input_error(fname, key, std::to_string(n) + " entries, data_format.pixels_per_column says " +
                                        std::to_string(m.pixels_per_column));
  }
  if (!j.contains("lidar_origin_to_beam_origin_mm") || !j["lidar_origin_to_beam_origin_mm"].is_number())
    throw input_error(fname, "lidar_origin_to_beam_origin_mm", "missing or not a number");
  m.lidar_origin_to_beam_origin_mm = j["lidar_origin_to_beam_origin_mm"].get<double>();
  if (j.contains("lidar_to_sensor_transform")) {
    const auto t = numbers(j, fname, "lidar_to_sensor_transform");
    if (t.size() != 16) throw input_error(fname, "lidar_to_sensor_transform", "expected 16 numbers (4x4 row-major)");
    std::copy(t.begin(), t.end(), m.lidar_to_sensor.begin());
  }
  m.layout();  // checks the beams (finite, strictly descending)
  return m;
}

int OusterFrame::valid_columns() const {
  int n = 0;
  for (auto v : column_valid) n += v;
  return n;
}

namespace {

// The frames read so far and the current record's number, for frame_for's check and its errors.
struct FrameAssembly {
  std::string fname;
  int H = 0, W = 0;
  std::vector<OusterFrame> frames;
  // Each frame costs rows x columns cells however few of its columns arrive, so a frame id that
  // changes every column made a 64 KB file cost hundreds of MB (found by the fuzz target). Between
  // the first and the last frame (which a capture may cut) a frame must hold at least half its
  // columns: real captures hold all of them, and memory stays a few times the file's size.
  int arrived = 0;  // columns of frames.back() so far
  long record = 0;

  // The frame with this id: the last one, or a new empty one after it.
  OusterFrame& frame_for(std::uint32_t id) {
    if (frames.empty() || frames.back().frame_id != id) {
      if (frames.size() >= 2 && arrived < (W + 1) / 2)
        throw input_error(fname, "record " + std::to_string(record) + " frame id",
                          "frame " + std::to_string(frames.back().frame_id) + " ends after " + std::to_string(arrived) +
                              " of its " + std::to_string(W) + " columns, between frames " +
                              std::to_string(frames[frames.size() - 2].frame_id) + " and " + std::to_string(id) +
                              " (frame ids out of order, or packets of more than one sensor?)");
      arrived = 0;
      OusterFrame f;
      f.frame_id = id;
      f.rows = H;
      f.cols = W;
      const std::size_t cells = static_cast<std::size_t>(H) * W;
      f.range_mm.assign(cells, 0);
      f.reflectivity.assign(cells, 0);
      f.signal.assign(cells, 0);
      f.nir.assign(cells, 0);
      f.column_valid.assign(W, 0);
      frames.push_back(std::move(f));
    }
    return frames.back();
  }
};

// The UDP payload of a record if it is an IPv4/UDP packet (one VLAN tag at most) to `port`, with
// its size in `payload`; nullptr for any other record.
const std::uint8_t* udp_payload_to(const pcap_pkthdr* header, const std::uint8_t* data, int port,
                                   std::size_t& payload) {
  std::size_t at = 14;
  if (header->caplen < at) return nullptr;
  std::uint16_t ether = static_cast<std::uint16_t>(data[12] << 8 | data[13]);
  if (ether == 0x8100 && header->caplen >= 18) {  // one VLAN tag
    ether = static_cast<std::uint16_t>(data[16] << 8 | data[17]);
    at = 18;
  }
  if (ether != 0x0800 || header->caplen < at + 20) return nullptr;  // IPv4 only
  const std::size_t ihl = (data[at] & 0x0F) * 4u;
  if (data[at + 9] != 17 || header->caplen < at + ihl + 8) return nullptr;  // UDP only
  const std::uint8_t* udp = data + at + ihl;
  if ((udp[2] << 8 | udp[3]) != port) return nullptr;
  payload = header->caplen - (at + ihl + 8);
  return udp + 8;
}

// One column's pixels (measurement id mid) into frame f.
void decode_column_pixels(const std::uint8_t* col, const Profile& profile, int H, int W, int mid, OusterFrame& f) {
  for (int r = 0; r < H; ++r) {
    const std::uint8_t* px = col + profile.column_header + static_cast<std::size_t>(r) * profile.pixel_bytes;
    const std::size_t cell = static_cast<std::size_t>(r) * W + mid;
    if (profile.legacy) {
      f.range_mm[cell] = le<std::uint32_t>(px) & 0xFFFFFu;
      f.reflectivity[cell] = le<std::uint16_t>(px + 4);
      f.signal[cell] = le<std::uint16_t>(px + 6);
      f.nir[cell] = le<std::uint16_t>(px + 8);
    } else if (profile.pixel_bytes == 12) {
      f.range_mm[cell] = le<std::uint32_t>(px) & 0x7FFFFu;
      f.reflectivity[cell] = px[4];
      f.signal[cell] = le<std::uint16_t>(px + 6);
      f.nir[cell] = le<std::uint16_t>(px + 8);
    } else {
      f.range_mm[cell] = (le<std::uint16_t>(px) & 0x7FFFu) * 8u;
      f.reflectivity[cell] = px[2];
      f.nir[cell] = px[3];
    }
  }
}

// One lidar packet's columns (payload p) into their frames; the packet counts for the frame of its last column.
void decode_packet(const std::uint8_t* p, const OusterMetadata& meta, const Profile& profile, FrameAssembly& a) {
  const int H = a.H, W = a.W;
  const std::size_t column_bytes =
      profile.column_header + static_cast<std::size_t>(H) * profile.pixel_bytes + (profile.legacy ? 4 : 0);
  const std::uint32_t packet_frame = profile.legacy ? 0 : le<std::uint16_t>(p + 2);
  const std::uint8_t* columns = profile.legacy ? p : p + 32;
  OusterFrame* frame = nullptr;
  for (int c = 0; c < meta.columns_per_packet; ++c) {
    const std::uint8_t* col = columns + c * column_bytes;
    const int mid = le<std::uint16_t>(col + 8);
    const std::uint32_t id = profile.legacy ? le<std::uint16_t>(col + 10) : packet_frame;
    bool valid = false;
    if (profile.legacy) valid = le<std::uint32_t>(col + column_bytes - 4) == 0xFFFFFFFFu;
    else valid = (le<std::uint16_t>(col + 10) & 1u) != 0;
    if (mid >= W)
      throw input_error(a.fname, "record " + std::to_string(a.record) + " measurement id",
                        std::to_string(mid) + " is beyond columns_per_frame " + std::to_string(W));
    OusterFrame& f = a.frame_for(id);
    frame = &f;
    ++a.arrived;
    if (!valid) continue;
    f.column_valid[mid] = 1;
    decode_column_pixels(col, profile, H, W, mid, f);
  }
  if (frame) ++frame->packets;
}

}  // namespace

std::vector<OusterFrame> read_ouster_pcap(const fs::path& pcap_path, const OusterMetadata& meta) {
  const std::string fname = pcap_path.string();
  char err[PCAP_ERRBUF_SIZE] = {0};
  std::unique_ptr<pcap_t, void (*)(pcap_t*)> pcap(pcap_open_offline(pcap_path.c_str(), err), pcap_close);
  if (!pcap) throw input_error(fname, "file", std::string("libpcap cannot open it: ") + err);
  if (pcap_datalink(pcap.get()) != DLT_EN10MB)
    throw input_error(fname, "link type", "expected Ethernet, got " + std::to_string(pcap_datalink(pcap.get())));
  const Profile profile = profile_of(meta);
  const std::size_t size = meta.packet_bytes();
  FrameAssembly a;
  a.fname = fname;
  a.H = meta.pixels_per_column, a.W = meta.columns_per_frame;
  pcap_pkthdr* header = nullptr;
  const std::uint8_t* data = nullptr;
  for (a.record = 1;; ++a.record) {
    const int rc = pcap_next_ex(pcap.get(), &header, &data);
    if (rc == PCAP_ERROR_BREAK) break;
    if (rc != 1)
      throw input_error(fname, "record " + std::to_string(a.record), std::string("cannot be read: ") + pcap_geterr(pcap.get()));
    std::size_t payload = 0;
    const std::uint8_t* p = udp_payload_to(header, data, meta.udp_port_lidar, payload);
    if (!p) continue;
    if (payload != size)
      throw input_error(fname, "record " + std::to_string(a.record),
                        "lidar packet of " + std::to_string(payload) + " bytes, the metadata's " + meta.udp_profile_lidar +
                            " with " + std::to_string(a.H) + " beams x " + std::to_string(meta.columns_per_packet) +
                            " columns makes " + std::to_string(size) + " (wrong metadata file?)");
    decode_packet(p, meta, profile, a);
  }
  if (a.frames.empty())
    throw input_error(fname, "packets", "no lidar packets on UDP port " + std::to_string(meta.udp_port_lidar));
  return std::move(a.frames);
}

std::vector<pgm::Point> ouster_points(const OusterFrame& frame, const OusterMetadata& meta) {
  std::vector<pgm::Point> points;
  const double n = meta.lidar_origin_to_beam_origin_mm;
  const auto& T = meta.lidar_to_sensor;
  // Only columns that arrived valid hold returns (the reader writes no others).
  std::vector<int> columns;
  for (int c = 0; c < frame.cols; ++c)
    if (frame.column_valid.empty() || frame.column_valid[c]) columns.push_back(c);
  for (int r = 0; r < frame.rows; ++r) {
    const double phi = meta.beam_altitude_deg[r] * kDeg;
    const double theta_az = -meta.beam_azimuth_deg[r] * kDeg;
    for (const int c : columns) {
      const std::size_t cell = static_cast<std::size_t>(r) * frame.cols + c;
      const double range = frame.range_mm[cell];
      if (range <= 0) continue;
      // Encoder angle of the measurement id: the lidar frame's x axis points at id 0 and the
      // ids run clockwise seen from above.
      const double theta_enc = 2.0 * std::numbers::pi * (1.0 - static_cast<double>(c) / frame.cols);
      const double lx = (range - n) * std::cos(theta_enc + theta_az) * std::cos(phi) + n * std::cos(theta_enc);
      const double ly = (range - n) * std::sin(theta_enc + theta_az) * std::cos(phi) + n * std::sin(theta_enc);
      const double lz = (range - n) * std::sin(phi);
      pgm::Point p;
      p.x = static_cast<float>((T[0] * lx + T[1] * ly + T[2] * lz + T[3]) / 1000.0);
      p.y = static_cast<float>((T[4] * lx + T[5] * ly + T[6] * lz + T[7]) / 1000.0);
      p.z = static_cast<float>((T[8] * lx + T[9] * ly + T[10] * lz + T[11]) / 1000.0);
      p.intensity = static_cast<float>(std::min(frame.reflectivity[cell] / 255.0, 1.0));
      p.ring = r;
      points.push_back(p);
    }
  }
  return points;
}

fs::path ouster_metadata_for(const fs::path& pcap) {
  std::string stem = pcap.stem().string();
  for (;;) {
    const fs::path candidate = pcap.parent_path() / (stem + ".json");
    if (fs::is_regular_file(candidate)) return candidate;
    const auto cut = stem.rfind('_');
    if (cut == std::string::npos) break;
    stem.resize(cut);
  }
  throw input_error(pcap.string(), "metadata", "no JSON metadata beside it (same name, or the name without its last _parts)");
}

}  // namespace lidarsim::data
