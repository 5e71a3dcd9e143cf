#pragma once
// Ouster recordings: the sensor's JSON metadata and a pcap of its UDP lidar packets.
//
// The metadata gives the beams (beam_altitude_angles / beam_azimuth_angles, deg, row 0 the
// top beam), lidar_origin_to_beam_origin_mm, lidar_to_sensor_transform (4x4 row-major, mm) and
// the packet layout: data_format (columns_per_frame, columns_per_packet, pixels_per_column,
// udp_profile_lidar; absent before firmware 2.2 = the legacy layout).
//
// The pcap is read with libpcap (Ethernet / IPv4 / UDP); payloads on the lidar port of the
// profile's packet size are lidar packets, the rest (IMU packets) is skipped. Profiles parsed:
//   LEGACY                   16-byte column header (timestamp u64, measurement id u16, frame
//                            id u16, encoder u32), 12-byte pixels (range u32 low 20 bits mm,
//                            reflectivity u16, signal u16, ambient u16), status u32 per column
//                            (0xFFFFFFFF = valid).
//   RNG19_RFL8_SIG16_NIR16   32-byte packet header (type u16, frame id u16, ...), 12-byte
//                            column header (timestamp u64, measurement id u16, status u16, bit
//                            0 = valid), 12-byte pixels (range u32 low 19 bits mm, reflectivity
//                            u8, -, signal u16, NIR u16), 32-byte footer.
//   RNG15_RFL8_NIR8          as above with 4-byte pixels (range = (u16 & 0x7FFF) x 8 mm,
//                            reflectivity u8, NIR u8).
// A frame is every column with one frame id; its range image has rows = beams and columns =
// measurement ids (staggered, as the sensor measures them). A frame between the first and the
// last must hold at least half its columns (else an error: frame ids out of order or mixed).
#include <array>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "pgm/beam_layout.h"
#include "pgm/projection.h"

namespace lidarsim::data {

struct OusterMetadata {
  std::string path;
  std::string prod_line;         // "OS-1-128"
  std::string firmware;          // build_rev, "v2.3.0"
  std::string lidar_mode;        // "1024x10"
  std::string udp_profile_lidar = "LEGACY";
  int columns_per_frame = 0, columns_per_packet = 16, pixels_per_column = 0;
  int udp_port_lidar = 7502;
  std::vector<double> beam_altitude_deg, beam_azimuth_deg;
  double lidar_origin_to_beam_origin_mm = 0;
  std::array<double, 16> lidar_to_sensor = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};

  std::size_t packet_bytes() const;  // lidar packet size of the profile (throws for one we do not parse)
  // rows = beams (altitudes), columns = columns_per_frame, per-beam azimuth offsets (sign
  // flipped: Ouster's are clockwise). No range limits: the metadata does not state them.
  pgm::BeamLayout layout() const;
};

// Throws naming the file and the field that is missing or inconsistent (e.g. beam arrays of a
// length other than pixels_per_column).
OusterMetadata read_ouster_metadata(const std::filesystem::path& path);

struct OusterFrame {
  std::uint32_t frame_id = 0;
  int rows = 0, cols = 0;
  std::vector<std::uint32_t> range_mm;       // [rows * cols], 0 = no return
  std::vector<std::uint16_t> reflectivity;   // [rows * cols]
  std::vector<std::uint16_t> signal, nir;    // [rows * cols] (0 when the profile has none)
  std::vector<std::uint8_t> column_valid;    // [cols]: the column arrived and its status says valid
  int packets = 0;
  int valid_columns() const;
};

// Every frame of the pcap in order of arrival. Throws naming the pcap (and record) for a file
// libpcap cannot open, a link type other than Ethernet, or a packet on the lidar port whose size
// is not the profile's.
std::vector<OusterFrame> read_ouster_pcap(const std::filesystem::path& pcap, const OusterMetadata& meta);

// Points of a frame in the sensor frame (m), by the vendor's range-to-XYZ formula through the
// beam angles and the beam-origin offset, then lidar_to_sensor_transform; ring = beam row,
// intensity = reflectivity / 255 (capped at 1). Cells without a return give no point.
std::vector<pgm::Point> ouster_points(const OusterFrame& frame, const OusterMetadata& meta);

// The metadata JSON for a pcap: the same stem, or the stem with trailing "_<suffix>" parts
// removed one at a time ("X_lb_n3.pcap" -> "X_lb.json", "X.json"). Throws when none exists.
std::filesystem::path ouster_metadata_for(const std::filesystem::path& pcap);

}  // namespace lidarsim::data
