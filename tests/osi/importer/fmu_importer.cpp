// A minimal FMI 2.0 importer for tests/osi/test_fmu_deps.cpp: it links nothing but the C and C++
// runtime (no protobuf, no HDF5, no OpenMP), so every other library its process loads came with
// the FMU. Usage: fmu_importer <unpacked fmu dir> <SensorView trace> <SensorData trace out>
// (traces: each message preceded by its length, 4 bytes little-endian, as osi/trace.h writes).
// Each SensorView goes in through OSMPSensorViewIn, one fmi2DoStep, and OSMPSensorDataOut's bytes
// are written out. Any failure: one line on stderr, exit 1.
#include <dlfcn.h>

#include <cstdarg>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <string>

#include "infer/fmu/fmi2.h"

namespace {

[[noreturn]] void die(const std::string& what) {
  std::fprintf(stderr, "fmu_importer: %s\n", what.c_str());
  std::exit(1);
}

std::string slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) die(path + ": cannot be opened");
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

void logger(fmi2ComponentEnvironment, fmi2String, fmi2Status status, fmi2String category, fmi2String message, ...) {
  char text[2048];
  va_list args;
  va_start(args, message);
  std::vsnprintf(text, sizeof text, message, args);
  va_end(args);
  if (status >= fmi2Warning) std::fprintf(stderr, "fmu %s: %s\n", category, text);
}

template <typename F>
F* symbol(void* lib, const char* name) {
  auto* f = reinterpret_cast<F*>(dlsym(lib, name));
  if (!f) die(std::string("the FMU does not export ") + name);
  return f;
}

fmi2Integer low(std::uintptr_t a) { return static_cast<fmi2Integer>(static_cast<std::uint32_t>(a & 0xffffffffu)); }
fmi2Integer high(std::uintptr_t a) { return static_cast<fmi2Integer>(static_cast<std::uint32_t>(std::uint64_t(a) >> 32)); }

}  // namespace

int main(int argc, char** argv) {
  if (argc != 4) die("usage: fmu_importer <unpacked fmu dir> <SensorView trace> <SensorData trace out>");
  const std::string dir = argv[1];
  const std::string xml = slurp(dir + "/modelDescription.xml");
  const auto at = xml.find(" guid=\"");
  if (at == std::string::npos) die("modelDescription.xml: no guid");
  const std::string guid = xml.substr(at + 7, xml.find('"', at + 7) - at - 7);

  void* lib = dlopen((dir + "/binaries/linux64/lidarsim_osi.so").c_str(), RTLD_NOW | RTLD_LOCAL);
  if (!lib) die(dlerror());
  auto* instantiate = symbol<fmi2InstantiateTYPE>(lib, "fmi2Instantiate");
  auto* set_int = symbol<fmi2SetIntegerTYPE>(lib, "fmi2SetInteger");
  auto* get_int = symbol<fmi2GetIntegerTYPE>(lib, "fmi2GetInteger");
  auto* do_step = symbol<fmi2DoStepTYPE>(lib, "fmi2DoStep");
  auto* free_instance = symbol<fmi2FreeInstanceTYPE>(lib, "fmi2FreeInstance");
  fmi2CallbackFunctions callbacks{};
  callbacks.logger = logger;
  const std::string resources = "file://" + dir + "/resources";
  fmi2Component c = instantiate("sensor", fmi2CoSimulation, guid.c_str(), resources.c_str(), &callbacks, 0, 0);
  if (!c) die("fmi2Instantiate failed");

  const std::string in = slurp(argv[2]);
  std::string out;
  const fmi2ValueReference in_vr[3] = {0, 1, 2}, out_vr[3] = {3, 4, 5};
  double t = 0;
  for (std::size_t pos = 0; pos < in.size();) {
    if (in.size() - pos < 4) die(std::string(argv[2]) + ": torn length");
    std::uint32_t n = 0;
    for (int b = 0; b < 4; ++b) n |= static_cast<std::uint32_t>(static_cast<unsigned char>(in[pos + b])) << (8 * b);
    pos += 4;
    if (in.size() - pos < n) die(std::string(argv[2]) + ": torn message");
    const auto address = reinterpret_cast<std::uintptr_t>(in.data() + pos);
    const fmi2Integer view[3] = {low(address), high(address), static_cast<fmi2Integer>(n)};
    if (set_int(c, in_vr, 3, view) != fmi2OK || do_step(c, t, 0.1, 1) != fmi2OK) die("fmi2DoStep failed");
    fmi2Integer data[3] = {0, 0, 0};
    if (get_int(c, out_vr, 3, data) != fmi2OK || data[2] <= 0) die("no OSMPSensorDataOut");
    const auto* bytes = reinterpret_cast<const char*>(static_cast<std::uintptr_t>(static_cast<std::uint32_t>(data[0])) |
                                                      static_cast<std::uintptr_t>(static_cast<std::uint32_t>(data[1])) << 32);
    const auto size = static_cast<std::uint32_t>(data[2]);
    for (int b = 0; b < 4; ++b) out.push_back(static_cast<char>((size >> (8 * b)) & 0xffu));
    out.append(bytes, size);
    pos += n;
    t += 0.1;
  }
  free_instance(c);
  std::ofstream file(argv[3], std::ios::binary);
  if (!file.write(out.data(), static_cast<std::streamsize>(out.size())) || !file.flush()) die(std::string(argv[3]) + ": write failed");
  return 0;
}
