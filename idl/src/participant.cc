// Participant: domain (explicit config) + participant lifetime.
#include "craftscan/dds/participant.h"

#include <dds/dds.h>

#include <filesystem>
#include <string>
#include <string_view>
#include <system_error>

namespace craftscan::dds {
namespace {

void SetError(std::string* error, std::string message) {
  if (error) *error = std::move(message);
}

// Checks that the files named in a comma-separated Cyclone config list
// exist (Cyclone itself only logs "cannot open"). XML fragments are skipped
// whole (they may contain commas); items with ${VAR} are left to Cyclone.
bool CheckConfigFiles(const std::string& config, std::string* why) {
  constexpr std::string_view kClose = "</CycloneDDS>";
  std::size_t pos = 0;
  while ((pos = config.find_first_not_of(" \t\r\n,", pos)) != std::string::npos) {
    if (config[pos] == '<') {
      const std::size_t close = config.find(kClose, pos);
      if (close == std::string::npos) return true;  // malformed: Cyclone says where
      pos = close + kClose.size();
      continue;
    }
    std::size_t end = config.find(',', pos);
    if (end == std::string::npos) end = config.size();
    std::string path = config.substr(pos, end - pos);
    pos = end;
    path.erase(path.find_last_not_of(" \t\r\n") + 1);
    if (path.rfind("file://", 0) == 0) path.erase(0, 7);
    if (path.find('$') != std::string::npos) continue;
    std::error_code ec;
    if (!std::filesystem::is_regular_file(path, ec)) {
      SetError(why, "config file '" + path + "' does not exist");
      return false;
    }
  }
  return true;
}

}  // namespace

bool ParticipantOptions::IsValid(std::string* why) const {
  if (domain_id > kMaxDomainId) {
    SetError(why, "domain_id " + std::to_string(domain_id) + " is above " +
                      std::to_string(kMaxDomainId));
    return false;
  }
  return config.empty() || CheckConfigFiles(config, why);
}

std::string ConfigFileUri(std::string_view path) { return "file://" + std::string(path); }

std::string LoopbackOnlyConfigXml() {
  return "<CycloneDDS><Domain>"
         "<General><Interfaces><NetworkInterface name=\"lo\"/></Interfaces>"
         "<AllowMulticast>false</AllowMulticast></General>"
         "<Discovery><ParticipantIndex>auto</ParticipantIndex>"
         "<MaxAutoParticipantIndex>20</MaxAutoParticipantIndex>"
         "<Peers><Peer address=\"127.0.0.1\"/></Peers></Discovery>"
         "</Domain></CycloneDDS>";
}

std::shared_ptr<Participant> Participant::Create(const ParticipantOptions& options,
                                                 std::string* error) {
  std::string why;
  if (!options.IsValid(&why)) {
    SetError(error, "participant: " + why);
    return nullptr;
  }
  dds_entity_t domain = 0;
  if (!options.config.empty()) {
    domain = dds_create_domain(options.domain_id, options.config.c_str());
    if (domain == DDS_RETCODE_PRECONDITION_NOT_MET) {
      SetError(error, "participant: domain " + std::to_string(options.domain_id) +
                          " already exists in this process (create further participants "
                          "of it with an empty config)");
      return nullptr;
    }
    if (domain < 0) {
      SetError(error, "participant: Cyclone rejected the configuration for domain " +
                          std::to_string(options.domain_id) + " (" + dds_strretcode(domain) +
                          "; its log on stderr names the element)");
      return nullptr;
    }
  }
  const dds_entity_t participant = dds_create_participant(options.domain_id, nullptr, nullptr);
  if (participant < 0) {
    if (domain > 0) dds_delete(domain);
    SetError(error, "participant: cannot create a participant in domain " +
                        std::to_string(options.domain_id) + " (" + dds_strretcode(participant) +
                        "; with CYCLONEDDS_URI set, check that configuration)");
    return nullptr;
  }
  return std::shared_ptr<Participant>(new Participant(options.domain_id, domain, participant));
}

Participant::~Participant() {
  dds_delete(participant_);
  if (domain_ > 0) dds_delete(domain_);
}

}  // namespace craftscan::dds
