// Frame pairing (pairing.h).
#include "pairing.h"

namespace craftscan::aravis {

std::string_view ToString(Pairing pairing) {
  return pairing == Pairing::kFrameId ? "frame_id" : "timestamp";
}

std::uint64_t FrameIdCounter::Count(std::uint64_t raw_id) {
  if (!have_base_) {
    have_base_ = true;
    last_raw_ = raw_id;
    count_ = 0;
    return 0;
  }
  constexpr std::uint64_t k16 = 0xFFFF;
  std::uint64_t delta = 0;
  if (raw_id <= k16 && last_raw_ <= k16) {
    // 16-bit block ids run 1..65535 then wrap to 1 (0 is never used).
    delta = raw_id >= last_raw_ ? raw_id - last_raw_ : raw_id + k16 - last_raw_;
  } else if (raw_id >= last_raw_) {
    delta = raw_id - last_raw_;
  }
  last_raw_ = raw_id;
  count_ += delta;
  return count_;
}

PairDecision DecidePair(const FrameStamp& left, const FrameStamp& right, Pairing pairing,
                        std::int64_t tolerance_ns, bool streaming) {
  if (pairing == Pairing::kFrameId) {
    if (left.count == right.count) return PairDecision::kPair;
    return left.count < right.count ? PairDecision::kDropLeft : PairDecision::kDropRight;
  }
  const std::int64_t difference = left.device_ns - right.device_ns;
  if (difference <= tolerance_ns && -difference <= tolerance_ns) return PairDecision::kPair;
  if (!streaming) return PairDecision::kMismatch;
  return difference < 0 ? PairDecision::kDropLeft : PairDecision::kDropRight;
}

}  // namespace craftscan::aravis
