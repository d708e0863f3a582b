// An independent check of a BagIt 1.0 bag (RFC 8493) for tests: it shares no
// code with craftscan's BagWriter. The checksums are checked by coreutils'
// `sha256sum -c` run inside the bag; the structure rules are parsed here.
#pragma once

#include <ctime>
#include <filesystem>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "file_util.h"
#include "process_util.h"

namespace craftscan::testing {

// Runs `sha256sum -c <manifest>` with the bag as working folder; returns its
// exit code (−1 if it could not run) and its output in *output.
inline int RunSha256sumCheck(const std::string& bag, const std::string& manifest,
                             std::string* output) {
  TempDir temp("craftscan-bagcheck");
  const std::string log = temp.File("out.txt");
  SpawnOptions options;
  options.stdout_path = log;
  options.stderr_to_stdout = true;
  ChildProcess child;
  // (cd in a shell: Spawn has no working-folder option.) Paths are passed as
  // positional parameters, never spliced into the script.
  if (!Spawn({"/bin/sh", "-c", "cd \"$1\" && exec sha256sum -c \"$2\"", "sh", bag, manifest},
             options, &child)) {
    return -1;
  }
  const int rc = child.Wait(std::chrono::seconds(60));
  if (output) *output = ReadFile(log);
  return rc;
}

// What an RFC 8493 bag must satisfy, beyond its checksums: returns one line
// per broken rule (empty: the bag is well formed). `organization` and
// `identifier` are the expected Source-Organization and External-Identifier.
inline std::vector<std::string> BagStructureProblems(const std::string& bag,
                                                     const std::string& organization,
                                                     const std::string& identifier) {
  namespace fs = std::filesystem;
  std::vector<std::string> problems;
  const auto problem = [&](const std::string& what) { problems.push_back(what); };
  if (ReadFile(bag + "/bagit.txt") != "BagIt-Version: 1.0\nTag-File-Character-Encoding: UTF-8\n") {
    problem("bagit.txt is not exactly the two lines RFC 8493 §2.1.1 gives");
  }
  // Payload on disk: every regular file under data/.
  std::map<std::string, std::uintmax_t> payload;  // "data/..." → size
  if (!fs::is_directory(bag + "/data")) problem("no data/ folder");
  std::error_code ec;
  for (fs::recursive_directory_iterator it(bag + "/data", ec), end; !ec && it != end;
       it.increment(ec)) {
    if (it->is_regular_file()) {
      payload[fs::relative(it->path(), bag).generic_string()] = it->file_size();
    }
  }
  // manifest-sha256.txt: "<64 hex>  data/<path>", each payload file once.
  std::map<std::string, int> listed;
  {
    std::istringstream in(ReadFile(bag + "/manifest-sha256.txt"));
    for (std::string line; std::getline(in, line);) {
      if (line.size() < 67 || line.substr(64, 2) != "  " ||
          line.substr(0, 64).find_first_not_of("0123456789abcdef") != std::string::npos) {
        problem("manifest-sha256.txt line '" + line + "' is not '<sha256>  <path>'");
        continue;
      }
      // RFC 8493 §2.1.3: %25, %0D and %0A stand for '%', CR and LF.
      std::string path = line.substr(66);
      for (const auto& [code, c] :
           {std::pair<std::string, std::string>{"%0D", "\r"}, {"%0A", "\n"}, {"%25", "%"}}) {
        for (std::size_t at = path.find(code); at != std::string::npos;
             at = path.find(code, at + c.size())) {
          path.replace(at, code.size(), c);
        }
      }
      ++listed[path];
    }
  }
  for (const auto& [path, count] : listed) {
    if (count != 1) problem(path + " is listed " + std::to_string(count) + " times");
    if (!payload.count(path)) problem(path + " is listed but is not in the payload");
  }
  for (const auto& [path, size] : payload) {
    if (!listed.count(path)) problem(path + " is in the payload but not in the manifest");
  }
  // bag-info.txt: "Label: value" lines.
  std::map<std::string, std::string> info;
  {
    std::istringstream in(ReadFile(bag + "/bag-info.txt"));
    for (std::string line; std::getline(in, line);) {
      const std::size_t colon = line.find(": ");
      if (colon == std::string::npos) {
        problem("bag-info.txt line '" + line + "' is not 'Label: value'");
        continue;
      }
      info[line.substr(0, colon)] = line.substr(colon + 2);
    }
  }
  if (info["Source-Organization"] != organization) {
    problem("Source-Organization is '" + info["Source-Organization"] + "', not '" + organization +
            "'");
  }
  if (info["External-Identifier"] != identifier) {
    problem("External-Identifier is '" + info["External-Identifier"] + "', not '" + identifier +
            "'");
  }
  char today[16];
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&now, &tm);
  std::strftime(today, sizeof today, "%Y-%m-%d", &tm);
  if (info["Bagging-Date"] != today) {
    problem("Bagging-Date is '" + info["Bagging-Date"] + "', not today (" + today + ")");
  }
  std::uintmax_t octets = 0;
  for (const auto& [path, size] : payload) octets += size;
  const std::string oxum = std::to_string(octets) + "." + std::to_string(payload.size());
  if (info["Payload-Oxum"] != oxum) {
    problem("Payload-Oxum is '" + info["Payload-Oxum"] + "', the payload is " + oxum);
  }
  // tagmanifest-sha256.txt lists the tag files.
  std::set<std::string> tags;
  {
    std::istringstream in(ReadFile(bag + "/tagmanifest-sha256.txt"));
    for (std::string line; std::getline(in, line);) {
      if (line.size() > 66) tags.insert(line.substr(66));
    }
  }
  for (const char* tag : {"bagit.txt", "bag-info.txt", "manifest-sha256.txt"}) {
    if (!tags.count(tag)) problem(std::string("tagmanifest-sha256.txt does not list ") + tag);
  }
  return problems;
}

}  // namespace craftscan::testing
