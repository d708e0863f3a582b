// A DDS domain participant (RAII) and the Cyclone configuration it is
// created with.
//
// Configuration: with ParticipantOptions::config empty, Cyclone reads
// CYCLONEDDS_URI as usual (the daemon's unit sets it to
// /etc/craftscan/cyclonedds.xml). With a config string, the participant
// creates its domain with exactly that configuration (CYCLONEDDS_URI is then
// ignored for that domain).
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <string_view>

namespace craftscan::dds {

// Cyclone maps domain ids to UDP ports (7400 + 250·id + ...); ids above 230
// overflow the port range.
inline constexpr uint32_t kMaxDomainId = 230;

struct ParticipantOptions {
  uint32_t domain_id = 0;  // 0..kMaxDomainId
  // Empty: the domain's configuration comes from CYCLONEDDS_URI (or Cyclone's
  // defaults). Otherwise a Cyclone configuration: XML ("<CycloneDDS>…"), a
  // file (an absolute path or a file:// URI), or a comma-separated list of
  // these, later items overriding earlier ones — e.g.
  // ConfigFileUri("/etc/craftscan/cyclonedds.xml") + "," + LoopbackOnlyConfigXml().
  std::string config;

  // False with *why (may be null) for a domain id above kMaxDomainId or a
  // config file that does not exist.
  bool IsValid(std::string* why) const;
};

// "file://" + path, the form Cyclone's config lists take for files. `path`
// should be absolute.
std::string ConfigFileUri(std::string_view path);

// A configuration fragment that keeps Cyclone on the loopback interface with
// unicast discovery among up to 20 processes per domain on this host (no
// multicast; nothing leaves the machine). For tests, benchmarks and a station
// whose clients all run on the station PC. Append it after the main config.
std::string LoopbackOnlyConfigXml();

// One DDS participant. Writers and readers hold a shared_ptr to it, so it
// outlives them. Destruction deletes the participant with everything in it
// and, if this participant created its domain (explicit config), the domain.
// Thread-safe (Cyclone's API is).
class Participant {
 public:
  // Creates the participant. With options.config set, also creates the
  // domain with that configuration; a domain id already in use in this
  // process with an explicit config fails ("domain 7 already exists in this
  // process") — create further participants of that domain with an empty
  // config: they join it (and must not outlive the participant that created
  // it). Returns null with *error (may be null) on invalid options or when
  // Cyclone rejects the configuration (its log, on stderr, says which
  // element) or cannot create the participant.
  static std::shared_ptr<Participant> Create(const ParticipantOptions& options, std::string* error);

  ~Participant();
  Participant(const Participant&) = delete;
  Participant& operator=(const Participant&) = delete;

  uint32_t domain_id() const { return domain_id_; }
  // The dds_entity_t of the participant (for the library's own use and for
  // callers that need the raw C API).
  int32_t handle() const { return participant_; }

 private:
  Participant(uint32_t domain_id, int32_t domain, int32_t participant)
      : domain_id_(domain_id), domain_(domain), participant_(participant) {}

  uint32_t domain_id_;
  int32_t domain_;  // dds_entity_t of a domain we created; 0 if none
  int32_t participant_;
};

}  // namespace craftscan::dds
