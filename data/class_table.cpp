#include "data/class_table.h"

#include <fstream>
#include <sstream>

#include "common/error.h"
#include "pgm/materials.h"

namespace lidarsim::data {

int ClassTable::map(int foreign_id) const {
  auto it = entries.find(foreign_id);
  return it == entries.end() ? -1 : it->second.class_id;
}

std::string ClassTable::name_of(int foreign_id) const {
  auto it = entries.find(foreign_id);
  return it == entries.end() ? "id " + std::to_string(foreign_id) + " (not in the table)" : it->second.name;
}

ClassTable read_class_table(const std::filesystem::path& path) {
  std::ifstream in(path);
  if (!in) throw input_error(path.string(), "file", "not found or cannot be opened");
  ClassTable table;
  table.path = path.string();
  std::string line;
  for (int number = 1; std::getline(in, line); ++number) {
    if (line.empty() || line[0] == '#') continue;
    const std::string where = "line " + std::to_string(number);
    std::stringstream ss(line);
    std::string id_text, name, cls;
    if (!std::getline(ss, id_text, ',') || !std::getline(ss, name, ',') || !std::getline(ss, cls))
      throw input_error(path.string(), where, "expected id,name,class");
    while (!cls.empty() && (cls.back() == '\r' || cls.back() == ' ')) cls.pop_back();
    int id = 0;
    try {
      std::size_t used = 0;
      id = std::stoi(id_text, &used);
      if (used != id_text.size()) throw std::invalid_argument("trailing");
    } catch (const std::exception&) {
      throw input_error(path.string(), where + " id", "'" + id_text + "' is not an integer");
    }
    if (table.entries.count(id)) throw input_error(path.string(), where + " id", std::to_string(id) + " appears twice");
    int class_id = -1;
    if (cls != "unmapped") {
      try {
        class_id = pgm::class_from_name(cls);
      } catch (const Error& e) {
        throw input_error(path.string(), where + " class", e.what());
      }
    }
    table.entries[id] = {name, class_id};
  }
  if (table.entries.empty()) throw input_error(path.string(), "table", "no entries");
  return table;
}

}  // namespace lidarsim::data
