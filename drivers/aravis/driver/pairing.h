// Pairing the left and right frames of the aravis driver (implementation
// header; pure, no I/O): per-camera frame ids made relative and unwrapped,
// and the decision whether two frames form a pair.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>

namespace craftscan::aravis {

enum class Pairing {
  kFrameId,    // the n-th frame of each camera since the streams (re)started
  kTimestamp,  // device timestamps within a tolerance (cameras on one clock: PTP or a shared host)
};
std::string_view ToString(Pairing pairing);  // "frame_id", "timestamp"

// Turns a camera's frame ids into a count since its first frame. GigE Vision
// 1.x block ids are 16 bits, count 1..65535 and skip 0 when they wrap; wider
// ids (GEV 2 extended ids, USB3 Vision) are used as they are. Frames must be
// fed in arrival order (one stream delivers them in order).
class FrameIdCounter {
 public:
  // Forgets the base: the next frame counts as 0.
  void Reset() { have_base_ = false; }
  bool has_base() const { return have_base_; }
  // The count of `raw_id` relative to the first frame since Reset().
  std::uint64_t Count(std::uint64_t raw_id);

 private:
  bool have_base_ = false;
  std::uint64_t last_raw_ = 0;
  std::uint64_t count_ = 0;
};

// One received frame as the pairing sees it.
struct FrameStamp {
  std::uint64_t count = 0;     // FrameIdCounter::Count of its id
  std::int64_t device_ns = 0;  // device timestamp (ns)
};

enum class PairDecision {
  kPair,       // the two frames belong together
  kDropLeft,   // the left frame is older than the right one: drop it, take the next left
  kDropRight,  // the right frame is older: drop it, take the next right
  kMismatch,   // timestamp pairing of a software-triggered pair: neither is usable (retrigger)
};

// Frame id pairing: equal counts pair, else the lower count is dropped.
// Timestamp pairing: |left − right| ≤ tolerance_ns pairs; otherwise, with
// `streaming` (hardware trigger: frames keep coming) the older frame is
// dropped, without it (one software trigger per pair) kMismatch.
PairDecision DecidePair(const FrameStamp& left, const FrameStamp& right, Pairing pairing,
                        std::int64_t tolerance_ns, bool streaming);

}  // namespace craftscan::aravis
