# Runs `craftscan-bench sim-depth` on one object and checks its JSON: the
# median depth error on object pixels below MAX_MEDIAN_MM and at least
# MIN_VALID_PCT % of object pixels with a disparity (and, if given, the 90th
# percentile below MAX_P90_MM). ARGS: more options (a CMake list).
#   cmake -DBENCH=... -DOBJECT=carved_box -DJSON=... -DMAX_MEDIAN_MM=0.3
#         -DMIN_VALID_PCT=95 [-DARGS=--projector] -P check_sim_depth.cmake
file(REMOVE "${JSON}")
execute_process(
  COMMAND "${BENCH}" sim-depth --object "${OBJECT}" --threads 2 --json "${JSON}" ${ARGS}
  RESULT_VARIABLE code)
if(NOT code EQUAL 0)
  message(FATAL_ERROR "craftscan-bench sim-depth exited with ${code}")
endif()
file(READ "${JSON}" text)
foreach(key depth_err_median_mm depth_err_p90_mm valid_pct disp_err_median_px min_disparity
            num_disparities render_ms match_ms)
  string(JSON value GET "${text}" ${key})
  message("${OBJECT} ${key} = ${value}")
endforeach()
string(JSON median GET "${text}" depth_err_median_mm)
string(JSON p90 GET "${text}" depth_err_p90_mm)
if(DEFINED MAX_P90_MM AND (p90 STREQUAL "null" OR p90 GREATER ${MAX_P90_MM}))
  message(FATAL_ERROR "p90 depth error ${p90} mm is not below ${MAX_P90_MM} mm")
endif()
string(JSON valid GET "${text}" valid_pct)
if(median STREQUAL "" OR median STREQUAL "null" OR median GREATER ${MAX_MEDIAN_MM})
  message(FATAL_ERROR "median depth error ${median} mm is not below ${MAX_MEDIAN_MM} mm")
endif()
if(valid LESS ${MIN_VALID_PCT})
  message(FATAL_ERROR "valid_pct ${valid} is below ${MIN_VALID_PCT} %")
endif()
