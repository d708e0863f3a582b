// Rigid poses as 4×4 homogeneous matrices (rotation | translation in mm, last
// row 0 0 0 1): quaternions, inversion, relative poses, pose error metrics
// and applying a pose to a cloud. Pure functions: thread-safe, never throw.
#pragma once

#include <opencv2/core/matx.hpp>

#include "craftscan/pipeline/common/point_cloud.h"

namespace craftscan {

// Rotation matrix of the unit quaternion (w, x, y, z) (Hamilton convention,
// active rotation). The quaternion is normalised first; a zero quaternion
// gives the identity.
cv::Matx33d RotationFromQuaternion(double w, double x, double y, double z);

// Angle of the rotation taking a's rotation to b's (the geodesic distance
// on SO(3)), in degrees, 0..180. Only the upper-left 3×3 blocks are used.
double RotationErrorDeg(const cv::Matx44d& a, const cv::Matx44d& b);

// Euclidean distance between the translations of a and b, in the units of
// the poses (mm for craftscan poses).
double TranslationErrorMm(const cv::Matx44d& a, const cv::Matx44d& b);

// Inverse of a rigid transform [R | t] (R assumed orthonormal).
cv::Matx44d InvertRigid(const cv::Matx44d& a_from_b);

// target_from_source = inverse(target_world_from) · source_world_from: maps
// points of the source scan into the target scan's frame. This is the
// ground truth a pairwise registration of source onto target should find.
cv::Matx44d RelativePose(const cv::Matx44d& world_from_target,
                         const cv::Matx44d& world_from_source);

// Applies a rigid transform to every point (and rotates normals); colours
// are kept.
PointCloud TransformCloud(const cv::Matx44d& to_from_cloud, const PointCloud& cloud);

}  // namespace craftscan
