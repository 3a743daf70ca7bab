/* A fake OpenHaptics HD library for the binding's tests, as strict as the real one where the
 * vendor's documentation and samples say so: devices by configured name ("Default Device" is the
 * first), re-initialising an open device is an error, an error stack (hdGetError pops the
 * oldest), forces only inside a frame, calibration queried inside a frame and updated only after
 * the scheduler has started and with one supported style, a 1 kHz scheduler thread on absolute
 * deadlines, motor temperatures, the software force limit.
 * Build: gcc -shared -fPIC -O2 -o libHD.so fake_libhd.c -lpthread -lm
 * Environment: FAKEHD_NAMES="Left Device,Right Device" (the configured names, default those),
 * FAKEHD_LOG=file (appends a line per hdInitDevice / hdDisableDevice / error),
 * FAKEHD_CALIBRATION="0x5000,0x5002" (the devices' calibration status when first opened).
 * Control functions (fakehd_*) let a test inject faults, move a stylus and read what was sent. */
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

typedef unsigned int HHD;
typedef unsigned int HDenum;
typedef unsigned int HDerror;
typedef unsigned int HDCallbackCode;
typedef unsigned long HDSchedulerHandle;
typedef struct { HDerror errorCode; int internalErrorCode; HHD hHD; } HDErrorInfo;
typedef HDCallbackCode (*HDSchedulerCallback)(void *);

#define NDEV 2
#define MAXCB 8
#define MAXERR 32
static char names[NDEV][64] = {"Left Device", "Right Device"};
static int names_read = 0;

static struct {
  int initialised, in_frame, force_output, clamping, ramping, soft_limit, calibration, styles, fault, pinned;
  double position[3], pin[3], force[3], max_force_sent, temperature;
  long frames;
} dev[NDEV];
static int current = -1;
static HDErrorInfo errors[MAXERR];
static int nerr = 0;
static HDSchedulerCallback callbacks[MAXCB];
static void *userdata[MAXCB];
static int ncb = 0, running = 0, started_once = 0;
static __thread int on_scheduler = 0; /* this thread is the scheduler's (its callbacks may calibrate) */
static long ticks = 0;
static pthread_t thread;
static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;

static void log_line(const char *what, const char *name) {
  const char *path = getenv("FAKEHD_LOG");
  if (!path) return;
  FILE *f = fopen(path, "a");
  if (f) { fprintf(f, "%s %s\n", what, name); fclose(f); }
}
static void set_error(HDerror code, int internal) {
  if (nerr < MAXERR) { errors[nerr].errorCode = code; errors[nerr].internalErrorCode = internal; errors[nerr].hHD = (HHD)current; nerr++; }
  char buf[32]; snprintf(buf, sizeof buf, "0x%04x", code); log_line("error", buf);
}
static void read_names(void) {
  if (names_read) return;
  names_read = 1;
  const char *cal = getenv("FAKEHD_CALIBRATION"); /* initial statuses, e.g. "0x5000,0x5002" */
  if (cal) { char *end; dev[0].calibration = (int)strtol(cal, &end, 0); if (*end == ',') dev[1].calibration = (int)strtol(end + 1, NULL, 0); }
  const char *env = getenv("FAKEHD_NAMES");
  if (!env) return;
  char copy[256]; strncpy(copy, env, sizeof copy - 1); copy[sizeof copy - 1] = 0;
  int i = 0;
  for (char *tok = strtok(copy, ","); tok && i < NDEV; tok = strtok(NULL, ","), i++) { strncpy(names[i], tok, 63); }
}

HHD hdInitDevice(const char *name) {
  read_names();
  for (int i = 0; i < NDEV; i++) {
    if (name == NULL || strcmp(name, names[i]) == 0 || (i == 0 && strcmp(name, "Default Device") == 0)) {
      if (dev[i].initialised) { set_error(0x0301, 0); return 0xFFFFFFFF; } /* HD_DEVICE_ALREADY_INITIATED */
      dev[i].initialised = 1; current = i;
      if (dev[i].calibration == 0) dev[i].calibration = 0x5000; /* unless a test set it */
      if (dev[i].styles == 0) dev[i].styles = (1 << 1) | (1 << 2); /* auto and inkwell */
      log_line("init", names[i]);
      return (HHD)i;
    }
  }
  set_error(0x0303, 0); /* HD_COMM_CONFIG_ERROR: no such configured device */
  return 0xFFFFFFFF;
}
void hdDisableDevice(HHD h) { if (h < NDEV) { dev[h].initialised = 0; log_line("disable", names[h]); } }
void hdMakeCurrentDevice(HHD h) { if (h < NDEV && dev[h].initialised) current = (int)h; else set_error(0x0104, 0); }
HHD hdGetCurrentDevice(void) { return (HHD)current; }
HDErrorInfo hdGetError(void) {
  HDErrorInfo e = {0, 0, 0xFFFFFFFF};
  if (nerr > 0) { e = errors[0]; memmove(errors, errors + 1, sizeof(HDErrorInfo) * (nerr - 1)); nerr--; }
  return e;
}
const char *hdGetErrorString(HDerror code) { (void)code; return "fake error"; }

void hdBeginFrame(HHD h) {
  if (h >= NDEV || !dev[h].initialised) { set_error(0x0104, 0); return; }
  if (dev[h].in_frame) { set_error(0x0400, 0); return; }
  dev[h].in_frame = 1; current = (int)h;
  if (dev[h].pinned) {
    memcpy(dev[h].position, dev[h].pin, sizeof(double) * 3);
  } else { /* the stylus moves on a 3 mm circle about the device's origin (2 s a turn), in millimetres */
    double t = ticks * 1e-3 * 3.14159265;
    dev[h].position[0] = (h == 0 ? -3.0 : 3.0) * sin(t);
    dev[h].position[1] = 2.0 * cos(t) - 2.0;
    dev[h].position[2] = 0.0;
  }
  if (dev[h].fault) set_error(0x0300, 42);
}
void hdEndFrame(HHD h) {
  if (h >= NDEV || !dev[h].in_frame) { set_error(0x0401, 0); return; }
  dev[h].in_frame = 0; dev[h].frames++;
}
void hdGetDoublev(HDenum p, double *v) {
  if (current < 0) { set_error(0x0104, 0); return; }
  switch (p) {
    case 0x2050: memcpy(v, dev[current].position, sizeof(double) * 3); break; /* HD_CURRENT_POSITION */
    case 0x2700: memcpy(v, dev[current].force, sizeof(double) * 3); break;    /* HD_CURRENT_FORCE */
    case 0x2603: v[0] = 3.3; break;                                            /* HD_NOMINAL_MAX_FORCE */
    case 0x2604: v[0] = 0.88; break;                                           /* HD_NOMINAL_MAX_CONTINUOUS_FORCE */
    case 0x2602: v[0] = 0.7; break;                                            /* HD_NOMINAL_MAX_STIFFNESS, N/mm */
    case 0x2605: for (int i = 0; i < 6; i++) v[i] = i < 3 ? dev[current].temperature : 0.0; break; /* HD_MOTOR_TEMPERATURE */
    default: set_error(0x0100, 0);
  }
}
void hdGetIntegerv(HDenum p, int *v) {
  if (current < 0) { set_error(0x0104, 0); return; }
  switch (p) {
    case 0x2000: v[0] = (ticks / 500) % 2; break; /* HD_CURRENT_BUTTONS: toggles every 0.5 s */
    case 0x2555: v[0] = dev[current].styles; break; /* HD_CALIBRATION_STYLE: the supported styles */
    default: set_error(0x0100, 0);
  }
}
void hdSetDoublev(HDenum p, const double *v) {
  if (current < 0) { set_error(0x0104, 0); return; }
  if (p != 0x2700) { set_error(0x0100, 0); return; }
  if (!dev[current].in_frame) { set_error(0x0102, 0); return; } /* force outside a frame */
  double m = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  if (m > 3.3 && !dev[current].clamping) { set_error(0x0201, 0); return; } /* HD_EXCEEDED_MAX_FORCE */
  memcpy(dev[current].force, v, sizeof(double) * 3);
  if (m > dev[current].max_force_sent) dev[current].max_force_sent = m;
}
void hdEnable(HDenum cap) {
  if (current < 0) { set_error(0x0104, 0); return; }
  if (cap == 0x4000) dev[current].force_output = 1;
  else if (cap == 0x4001) dev[current].clamping = 1;
  else if (cap == 0x4002) dev[current].ramping = 1;
  else if (cap == 0x4003) dev[current].soft_limit = 1;
  else set_error(0x0100, 0);
}
void hdDisable(HDenum cap) { if (current >= 0 && cap == 0x4000) dev[current].force_output = 0; }
int hdIsEnabled(HDenum cap) { return current >= 0 && cap == 0x4000 ? dev[current].force_output : 0; }
int hdCheckCalibration(void) {
  if (current < 0) { set_error(0x0104, 0); return 0; }
  if (!(running || on_scheduler) || !dev[current].in_frame) { set_error(0x0102, 1); return 0; } /* the vendor's order: scheduler running, in a frame */
  return dev[current].calibration;
}
void hdUpdateCalibration(HDenum style) {
  if (current < 0) { set_error(0x0104, 0); return; }
  if (!(running || on_scheduler)) { set_error(0x0102, 2); return; }
  if (style == 0 || (style & (style - 1)) != 0 || !(style & dev[current].styles)) { set_error(0x0101, 3); return; } /* one supported style */
  if (dev[current].calibration == 0x5001) dev[current].calibration = 0x5000;
}

static void *scheduler(void *arg) {
  (void)arg;
  on_scheduler = 1;
  struct timespec next;
  clock_gettime(CLOCK_MONOTONIC, &next);
  while (1) {
    pthread_mutex_lock(&lock);
    int go = running, n = ncb;
    pthread_mutex_unlock(&lock);
    if (!go) break;
    for (int i = 0; i < n; i++) {
      if (callbacks[i] && callbacks[i](userdata[i]) == 0) callbacks[i] = NULL; /* HD_CALLBACK_DONE */
    }
    for (int d = 0; d < NDEV; d++) if (dev[d].in_frame) { set_error(0x0402, 0); dev[d].in_frame = 0; } /* HD_FRAME_ERROR */
    ticks++;
    next.tv_nsec += 1000000;
    if (next.tv_nsec >= 1000000000) { next.tv_nsec -= 1000000000; next.tv_sec++; }
    clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, NULL);
  }
  return NULL;
}
HDSchedulerHandle hdScheduleAsynchronous(HDSchedulerCallback cb, void *data, unsigned short priority) {
  (void)priority;
  if (ncb >= MAXCB) { set_error(0x0501, 0); return 0; }
  callbacks[ncb] = cb; userdata[ncb] = data;
  return (HDSchedulerHandle)(++ncb);
}
void hdUnschedule(HDSchedulerHandle h) { if (h >= 1 && h <= (HDSchedulerHandle)ncb) callbacks[h - 1] = NULL; }
void hdStartScheduler(void) {
  pthread_mutex_lock(&lock);
  if (running) { pthread_mutex_unlock(&lock); return; }
  running = 1; started_once = 1;
  pthread_mutex_unlock(&lock);
  pthread_create(&thread, NULL, scheduler, NULL);
}
void hdStopScheduler(void) {
  pthread_mutex_lock(&lock);
  int was = running; running = 0;
  pthread_mutex_unlock(&lock);
  if (was) pthread_join(thread, NULL);
}

/* test controls */
void fakehd_set_calibration(int device, int status) { dev[device].calibration = status; }
void fakehd_set_styles(int device, int styles) { dev[device].styles = styles; }
void fakehd_set_fault(int device, int on) { dev[device].fault = on; }
void fakehd_set_temperature(int device, double t) { dev[device].temperature = t; }
void fakehd_pin(int device, double x, double y, double z) { dev[device].pinned = 1; dev[device].pin[0] = x; dev[device].pin[1] = y; dev[device].pin[2] = z; }
double fakehd_max_force(int device) { return dev[device].max_force_sent; }
double fakehd_force(int device, int axis) { return dev[device].force[axis]; }
long fakehd_frames(int device) { return dev[device].frames; }
long fakehd_ticks(void) { return ticks; }
int fakehd_in_frame(int device) { return dev[device].in_frame; }
int fakehd_force_enabled(int device) { return dev[device].force_output; }
int fakehd_ramping(int device) { return dev[device].ramping; }
int fakehd_soft_limit(int device) { return dev[device].soft_limit; }
int fakehd_pending_errors(void) { return nerr; }
