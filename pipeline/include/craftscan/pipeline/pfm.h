// Portable Float Map (PFM) reading and writing, single channel ("Pf") and
// three channel ("PF"), either byte order.
#pragma once

#include <string>

#include <opencv2/core/mat.hpp>

namespace craftscan {

// Reads a PFM file into CV_32FC1 or CV_32FC3, top row first. Returns false and
// sets *error (naming the file and what is wrong) on a missing, truncated or
// malformed file. Thread-safe.
bool ReadPfm(const std::string& path, cv::Mat* image, std::string* error);

// Writes CV_32FC1/CV_32FC3 as little-endian PFM. Returns false with *error on
// failure. Thread-safe.
bool WritePfm(const std::string& path, const cv::Mat& image, std::string* error);

}  // namespace craftscan
