# The Debian package `craftscan` (CPack DEB): `cpack -G DEB` in the build
# folder makes craftscan_<version>_<arch>.deb from the install() rules —
# programs in /usr/bin, driver plugins in /usr/lib/craftscan/drivers, the
# console's files in /usr/share/craftscan/web, units, sysusers, udev rules,
# the sysctl drop-in and the example configs in /etc/craftscan (conffiles).
# Library dependencies come from dpkg-shlibdeps (package dpkg-dev) reading
# the ELF files; the maintainer scripts in packaging/debian create the user
# and tell systemd and udev only where systemd runs.
#
# CRAFTSCAN_NATIVE_ARCH is ON by default: such a package runs only on CPUs
# like the build machine's. A package for other machines is built with
# -DCRAFTSCAN_NATIVE_ARCH=OFF.

set(CPACK_GENERATOR DEB)
set(CPACK_PACKAGE_NAME craftscan)
set(CPACK_PACKAGE_VERSION ${PROJECT_VERSION})
set(CPACK_PACKAGE_VENDOR craftscan)
set(CPACK_PACKAGE_CONTACT "craftscan maintainers <craftscan@localhost>")
set(CPACK_PACKAGE_DESCRIPTION_SUMMARY
    "open 3D scanning station for museums: daemon, operator CLI, archiver, web console, worker")
# The first line is the synopsis, the rest the extended description.
set(CPACK_DEBIAN_PACKAGE_DESCRIPTION "${CPACK_PACKAGE_DESCRIPTION_SUMMARY}
craftscand captures stereo views of an object on a turntable (GigE or USB3
Vision cameras through Aravis, a GRBL turntable, or the simulated station),
reconstructs a model and writes every output atomically into a session
folder. craftscanctl, craftscan-record and the craftscan-web console talk to
it over DDS (Cyclone DDS); craftscan-worker reconstructs the scans of a
site's stations on other hosts.")
set(CPACK_PACKAGING_INSTALL_PREFIX /usr)
set(CPACK_DEBIAN_FILE_NAME DEB-DEFAULT)
set(CPACK_DEBIAN_PACKAGE_SECTION science)
set(CPACK_DEBIAN_PACKAGE_PRIORITY optional)
# Shared-library dependencies (libddsc0debian, OpenCV, PCL, Aravis, ...) from
# dpkg-shlibdeps; the rest by hand: the postinst's systemd-sysusers, udev for
# the camera rules, openssl for craftscan-dds-security-setup.
set(CPACK_DEBIAN_PACKAGE_SHLIBDEPS ON)
set(CPACK_DEBIAN_PACKAGE_DEPENDS "systemd | systemd-standalone-sysusers")
set(CPACK_DEBIAN_PACKAGE_RECOMMENDS "udev, openssl")
set(CPACK_STRIP_FILES ON)
# conffiles: dpkg keeps a site's edits to /etc/craftscan over upgrades.
set(CPACK_DEBIAN_PACKAGE_CONTROL_EXTRA
    ${CMAKE_CURRENT_LIST_DIR}/debian/conffiles
    ${CMAKE_CURRENT_LIST_DIR}/debian/postinst
    ${CMAKE_CURRENT_LIST_DIR}/debian/prerm
    ${CMAKE_CURRENT_LIST_DIR}/debian/postrm)
# Maintainer scripts 0755, conffiles 0644, whatever the checkout's modes.
set(CPACK_DEBIAN_PACKAGE_CONTROL_STRICT_PERMISSION TRUE)
include(CPack)
