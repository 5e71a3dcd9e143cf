#pragma once
// A foreign class ontology mapped onto ours, from a small CSV table file (data/ontologies/):
//   id,name,class      class = a pgm/materials.h class name, or "unmapped"
// Lines starting with '#' are comments. Unmapped ids (and ids not in the table) import as
// unlabeled; the reader counts them per foreign class so the importer can report them.
#include <filesystem>
#include <map>
#include <string>

namespace lidarsim::data {

struct ClassTable {
  struct Entry {
    std::string name;  // the foreign class name
    int class_id = -1;  // ours; -1 = unmapped
  };
  std::map<int, Entry> entries;
  std::string path;
  // Our class of a foreign id: -1 when unmapped or unknown.
  int map(int foreign_id) const;
  std::string name_of(int foreign_id) const;  // "id 42 (not in the table)" when unknown
};

// Throws naming the file, line and field for a malformed line, an unknown class name or a
// repeated id.
ClassTable read_class_table(const std::filesystem::path& path);

}  // namespace lidarsim::data
