# Runs `craftscan-bench scan` and checks its JSON against limits; a limit
# left undefined is not checked. Figures are printed either way.
#   cmake -DBENCH=... -DJSON=... -DSCAN_ARGS="--object;egg;--image-size;640x512"
#         [-DMAX_OUTLIER_PCT=x] [-DMIN_COMPLETENESS_PCT=x] [-DMAX_FUSED_P95_MM=x]
#         [-DMAX_OBB_ERROR_MM=x] [-DMIN_LARGEST_COMPONENT_PCT=x]
#         [-DMAX_OBB_ERROR_MM_2=x (one axis: 0, 1 or 2, the OBB's extents
#          largest first)] [-DMAX_BOX_EDGE_MEAN_MM=x] [-DMAX_BOX_EDGE_STD_MM=x]
#         [-DMAX_VIEW_POSE_ERR_DEG=x (every view's registered pose against
#          its true one, the largest over the views)]
#         -P check_scan_json.cmake
file(REMOVE "${JSON}")
execute_process(COMMAND "${BENCH}" scan ${SCAN_ARGS} --json "${JSON}" RESULT_VARIABLE code)
if(NOT code EQUAL 0)
  message(FATAL_ERROR "craftscan-bench scan exited with ${code}")
endif()
file(READ "${JSON}" text)
string(JSON status GET "${text}" status)
if(NOT status STREQUAL "ok")
  message(FATAL_ERROR "scan status '${status}':\n${text}")
endif()
string(JSON outlier GET "${text}" outlier_pct)
string(JSON completeness GET "${text}" completeness_pct)
string(JSON p95 GET "${text}" fused_to_truth_mm p95)
string(JSON largest GET "${text}" mesh_largest_component_pct)
message("outlier_pct ${outlier}, completeness_pct ${completeness}, fused p95 ${p95} mm, "
        "largest mesh component ${largest} %")
set(failures "")
macro(check_max value limit what)
  if(DEFINED ${limit})
    if(${value} GREATER ${${limit}})
      string(APPEND failures "${what} ${${value}} > ${${limit}}\n")
    endif()
  endif()
endmacro()
macro(check_min value limit what)
  if(DEFINED ${limit})
    if(${value} LESS ${${limit}})
      string(APPEND failures "${what} ${${value}} < ${${limit}}\n")
    endif()
  endif()
endmacro()
check_max(outlier MAX_OUTLIER_PCT "outlier_pct")
check_min(completeness MIN_COMPLETENESS_PCT "completeness_pct")
check_max(p95 MAX_FUSED_P95_MM "fused_to_truth p95 (mm)")
check_min(largest MIN_LARGEST_COMPONENT_PCT "mesh_largest_component_pct")
foreach(axis 0 1 2)
  string(JSON err GET "${text}" obb_error_mm ${axis})
  check_max(err MAX_OBB_ERROR_MM "|fused OBB - truth OBB| along axis ${axis} (mm)")
  check_max(err MAX_OBB_ERROR_MM_${axis} "|fused OBB - truth OBB| along axis ${axis} (mm)")
  # The truth along the fused box's own axes: the cloud's error alone, even
  # where two boxes of nearly equal volume lie in different orientations.
  string(JSON same GET "${text}" obb_error_same_axes_mm ${axis})
  check_max(same MAX_OBB_ERROR_MM "|fused OBB - truth along its axes| along axis ${axis} (mm)")
endforeach()
string(JSON edges ERROR_VARIABLE no_edges GET "${text}" box_edges_mm)
if(NOT no_edges)
  string(JSON edge_mean GET "${text}" box_edges_mm mean)
  string(JSON edge_std GET "${text}" box_edges_mm std)
  message("box edges: mean ${edge_mean} mm, std ${edge_std} mm")
  string(REGEX REPLACE "^-" "" edge_mean_abs "${edge_mean}")
  check_max(edge_mean_abs MAX_BOX_EDGE_MEAN_MM "|box edge mean error| (mm)")
  check_max(edge_std MAX_BOX_EDGE_STD_MM "box edge error std (mm)")
endif()
string(JSON pose_max GET "${text}" view_pose_err_deg 0 max)
message("view poses against the truth: max ${pose_max} deg")
check_max(pose_max MAX_VIEW_POSE_ERR_DEG "view pose error, max (deg)")
if(failures)
  message(FATAL_ERROR "scan figures outside their limits:\n${failures}${text}")
endif()
