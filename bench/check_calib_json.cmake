# Runs `craftscan-bench calib` on OpenCV's stereo sample images (9x6 inner
# corners, 25 mm squares) and checks its JSON: the interface scripts rely on
# (rms_left_px, rms_right_px, rms_stereo_px, epipolar_px, pairs_used) and the
# stereo RMS against OpenCV's own stereo_calib sample (0.634 px with its flags).
#   cmake -DBENCH=... -DPAIRS=... -DJSON=... -P check_calib_json.cmake
file(REMOVE "${JSON}")
execute_process(
  COMMAND "${BENCH}" calib --pairs "${PAIRS}" --board 9x6 --square 25 --json "${JSON}"
  RESULT_VARIABLE code)
if(NOT code EQUAL 0)
  message(FATAL_ERROR "craftscan-bench exited with ${code}")
endif()
file(READ "${JSON}" text)
foreach(key rms_left_px rms_right_px rms_stereo_px epipolar_px pairs_used verdict)
  string(JSON value GET "${text}" ${key})
  message("${key} = ${value}")
endforeach()
string(JSON rms GET "${text}" rms_stereo_px)
string(JSON used GET "${text}" pairs_used)
string(JSON total GET "${text}" pairs_total)
string(JSON epipolar GET "${text}" epipolar_px)
string(JSON n LENGTH "${text}" pairs)
if(NOT used EQUAL 13 OR NOT total EQUAL 13 OR NOT n EQUAL 13)
  message(FATAL_ERROR "expected 13 of 13 pairs used, got ${used} of ${total} (${n} listed)")
endif()
if(NOT rms GREATER 0 OR rms GREATER 0.634)
  message(FATAL_ERROR "rms_stereo_px ${rms} is worse than OpenCV's sample (0.634 px)")
endif()
if(NOT epipolar GREATER_EQUAL 0 OR epipolar GREATER 0.5)
  message(FATAL_ERROR "epipolar_px ${epipolar} outside [0, 0.5]")
endif()
