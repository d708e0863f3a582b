// Portable Float Map (PFM) reading and writing, single channel ("Pf") and
// three channel ("PF"), either byte order.
#pragma once

#include <string>

#include <opencv2/core/mat.hpp>

namespace craftscan {

// Reads a PFM file into CV_32FC1 or CV_32FC3 (BGR, like cv::imread), top row
// first; values are returned as stored (the header's scale only gives the byte
// order). Returns false and sets *error (naming the file and what is wrong; may
// be null) on a missing, truncated or malformed file, including a side ≤ 0 or
// > 32768 px. Never throws. Thread-safe.
bool ReadPfm(const std::string& path, cv::Mat* image, std::string* error);

// The bytes WritePfm writes for `image`, in *bytes, for a caller that writes
// them itself (with the Status-returning WriteFileAtomically). Returns false
// with *error (may be null; "PFM: <what>") and *bytes empty for an empty
// image, another type or a side > 32768 px. Never throws. Thread-safe.
bool EncodePfm(const cv::Mat& image, std::string* bytes, std::string* error);

// Writes CV_32FC1/CV_32FC3 (BGR) as little-endian PFM (scale -1, rows
// bottom-to-top, RGB). Returns false with *error (may be null) for an empty
// image, another type, a side > 32768 px or an I/O failure. The write is
// atomic (WriteFileAtomically): a crash never leaves a half-written file.
// Never throws. Thread-safe (for distinct paths).
bool WritePfm(const std::string& path, const cv::Mat& image, std::string* error);

}  // namespace craftscan
