/* C ABI of a native haptic driver plug-in, loaded by zona with dlopen (make_plugin_device).
 * A plug-in is a shared library exporting these symbols with C linkage. Units: SI, device
 * frame. zona calls read/write from its haptic thread at the haptic rate; they must not block.
 */
#ifndef ZONA_HAPTICS_PLUGIN_ABI_H
#define ZONA_HAPTICS_PLUGIN_ABI_H

#ifdef __cplusplus
extern "C" {
#endif

#define ZONA_HAPTIC_ABI_VERSION 1

/* Device limits and impedance reported by the plug-in. */
typedef struct ZonaHapticInfo {
  char name[32];          /* NUL-terminated */
  double max_force;       /* [N] */
  double max_stiffness;   /* [N/m] */
  double max_damping;     /* [N*s/m] */
  double mass;            /* effective moving mass [kg] */
  double damping;         /* physical damping [N*s/m] */
} ZonaHapticInfo;

/* Returns ZONA_HAPTIC_ABI_VERSION. */
int zona_haptic_abi_version(void);
/* Opens the device; `config` is free text from the command line. NULL on failure. */
void* zona_haptic_open(const char* config, ZonaHapticInfo* info);
/* Position [m] and velocity [m/s] at zona's haptic-clock time [s]; 0 on success. */
int zona_haptic_read(void* device, double time, double position[3], double velocity[3]);
/* Force to hold until the next call [N]; 0 on success. */
int zona_haptic_write(void* device, double time, const double force[3]);
/* Zeroes the force and releases the device. */
void zona_haptic_close(void* device);

#ifdef __cplusplus
}
#endif

#endif /* ZONA_HAPTICS_PLUGIN_ABI_H */
