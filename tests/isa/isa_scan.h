#pragma once
// Finds instructions beyond x86-64-v3 in the disassembly of a binary (objdump -d -C -w): any
// EVEX-encoded instruction (first opcode byte 0x62, which 64-bit mode gives to EVEX alone: every
// AVX-512 instruction, whatever its registers) and anything naming a zmm register, xmm16-31 /
// ymm16-31, an opmask register k0-k7 (the VEX-encoded mask instructions) or an AMX tile, and the
// AMX instructions that name no tile (ldtilecfg, sttilecfg, tilerelease).
// Functions whose name contains "avx512" are the dispatched kernels (nn/isa_avx512_begin.h) and
// may use them; every other function must not.
#include <cctype>
#include <cstdio>
#include <cstdlib>
#include <istream>
#include <sstream>
#include <string>
#include <vector>

namespace lidarsim::testing {

struct IsaFinding {
  std::string function;
  std::string instruction;  // the first offending one
};

// Whether one instruction (raw bytes as objdump prints them, "62 f1 7c ...", and its text) is
// beyond x86-64-v3.
inline bool beyond_v3(const std::string& bytes, const std::string& text) {
  std::istringstream in(bytes);
  std::string b;
  // Address-size and segment prefixes may precede an EVEX prefix.
  while (in >> b && (b == "67" || b == "26" || b == "2e" || b == "36" || b == "3e" || b == "64" || b == "65")) {
  }
  if (b == "62") return true;
  const std::size_t m = text.find_first_not_of(' ');
  const std::string mnemonic = m == std::string::npos ? "" : text.substr(m, text.find_first_of(" \t", m) - m);
  if (mnemonic == "ldtilecfg" || mnemonic == "sttilecfg" || mnemonic == "tilerelease") return true;
  // Registers as AT&T syntax prints them: %zmm5, %ymm17, %k1, %tmm0.
  for (std::size_t at = text.find('%'); at != std::string::npos; at = text.find('%', at + 1)) {
    std::size_t end = at + 1;
    while (end < text.size() && std::isalpha(static_cast<unsigned char>(text[end]))) ++end;
    const std::string name = text.substr(at + 1, end - at - 1);
    int number = -1;
    if (end < text.size() && std::isdigit(static_cast<unsigned char>(text[end]))) number = std::atoi(text.c_str() + end);
    if (number < 0) continue;
    if (name == "zmm" || name == "tmm" || (name == "k" && number <= 7)) return true;
    if ((name == "xmm" || name == "ymm") && number >= 16) return true;
  }
  return false;
}

// The functions of one disassembly (objdump -d -C -w output) that use instructions beyond
// x86-64-v3 and are not dispatched kernels; one finding per function.
inline std::vector<IsaFinding> scan_disassembly(std::istream& dis) {
  std::vector<IsaFinding> found;
  std::string line, function;
  bool reported = false;
  while (std::getline(dis, line)) {
    // "0000000000401000 <name>:" opens a function.
    const std::size_t lt = line.find(" <");
    if (!line.empty() && line[0] != ' ' && lt != std::string::npos && line.size() > 2 &&
        line.compare(line.size() - 2, 2, ">:") == 0) {
      function = line.substr(lt + 2, line.size() - lt - 4);
      reported = false;
      continue;
    }
    // "  401000:\t62 f1 7c 48 10 0f \tvmovups (%rdi),%zmm1"
    const std::size_t t1 = line.find('\t');
    if (t1 == std::string::npos || reported) continue;
    const std::size_t t2 = line.find('\t', t1 + 1);
    const std::string bytes = line.substr(t1 + 1, t2 == std::string::npos ? std::string::npos : t2 - t1 - 1);
    const std::string text = t2 == std::string::npos ? "" : line.substr(t2 + 1);
    if (text.empty() || function.find("avx512") != std::string::npos) continue;
    if (beyond_v3(bytes, text)) {
      found.push_back({function, text});
      reported = true;
    }
  }
  return found;
}

}  // namespace lidarsim::testing
