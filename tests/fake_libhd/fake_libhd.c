/* A fake OpenHaptics HD library for the binding's tests: two devices ("Left Device",
 * "Right Device"), frames, state get/set, force output with nominal limits, calibration,
 * errors, and a scheduler thread calling the scheduled callbacks at 1 kHz.
 * Build: gcc -shared -fPIC -O2 -o libHD.so fake_libhd.c -lpthread -lm
 * Control functions (fakehd_*) let a test inject faults and read what was sent. */
#include <math.h>
#include <pthread.h>
#include <stdio.h>
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
static const char *NAMES[NDEV] = {"Left Device", "Right Device"};

static struct {
  int initialised, in_frame, force_output, clamping, ramping, calibration, fault;
  double position[3], force[3], max_force_sent;
  long frames;
} dev[NDEV];
static int current = -1;
static HDErrorInfo last_error = {0, 0, 0xFFFFFFFF};
static HDSchedulerCallback callbacks[MAXCB];
static void *userdata[MAXCB];
static int ncb = 0, running = 0;
static long ticks = 0;
static pthread_t thread;
static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;

static void set_error(HDerror code, int internal) {
  if (last_error.errorCode == 0) { last_error.errorCode = code; last_error.internalErrorCode = internal; last_error.hHD = (HHD)current; }
}

HHD hdInitDevice(const char *name) {
  for (int i = 0; i < NDEV; i++) {
    if (name == NULL || strcmp(name, NAMES[i]) == 0) {
      if (dev[i].initialised) { set_error(0x0301, 0); return 0xFFFFFFFF; }
      dev[i].initialised = 1; current = i;
      if (dev[i].calibration == 0) dev[i].calibration = 0x5000; /* unless a test set it */
      return (HHD)i;
    }
  }
  set_error(0x0303, 0); /* HD_COMM_CONFIG_ERROR: no such configured device */
  return 0xFFFFFFFF;
}
void hdDisableDevice(HHD h) { if (h < NDEV) dev[h].initialised = 0; }
void hdMakeCurrentDevice(HHD h) { if (h < NDEV && dev[h].initialised) current = (int)h; else set_error(0x0104, 0); }
HHD hdGetCurrentDevice(void) { return (HHD)current; }
HDErrorInfo hdGetError(void) { HDErrorInfo e = last_error; last_error.errorCode = 0; last_error.internalErrorCode = 0; return e; }
const char *hdGetErrorString(HDerror code) { (void)code; return "fake error"; }

void hdBeginFrame(HHD h) {
  if (h >= NDEV || !dev[h].initialised) { set_error(0x0104, 0); return; }
  if (dev[h].in_frame) { set_error(0x0400, 0); return; }
  dev[h].in_frame = 1; current = (int)h;
  /* the stylus moves on a slow circle, in millimetres; a fault makes the device report one */
  double t = ticks * 1e-3;
  dev[h].position[0] = (h == 0 ? -20.0 : 20.0) + 10.0 * sin(t);
  dev[h].position[1] = 5.0 * cos(t);
  dev[h].position[2] = 1.0 * h;
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
    default: set_error(0x0100, 0);
  }
}
void hdGetIntegerv(HDenum p, int *v) {
  if (current < 0) { set_error(0x0104, 0); return; }
  switch (p) {
    case 0x2000: v[0] = (ticks / 500) % 2; break; /* HD_CURRENT_BUTTONS: toggles every 0.5 s */
    case 0x2555: v[0] = 1 << 1; break;            /* HD_CALIBRATION_STYLE: auto */
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
  else set_error(0x0100, 0);
}
void hdDisable(HDenum cap) { if (current >= 0 && cap == 0x4000) dev[current].force_output = 0; }
int hdIsEnabled(HDenum cap) { return current >= 0 && cap == 0x4000 ? dev[current].force_output : 0; }
int hdCheckCalibration(void) { return current >= 0 ? dev[current].calibration : 0x5002; }
void hdUpdateCalibration(HDenum style) { (void)style; if (current >= 0 && dev[current].calibration == 0x5001) dev[current].calibration = 0x5000; }

static void *scheduler(void *arg) {
  (void)arg;
  struct timespec period = {0, 1000000};
  while (1) {
    pthread_mutex_lock(&lock);
    int go = running, n = ncb;
    pthread_mutex_unlock(&lock);
    if (!go) break;
    for (int i = 0; i < n; i++) {
      if (callbacks[i] && callbacks[i](userdata[i]) == 0) callbacks[i] = NULL; /* HD_CALLBACK_DONE */
    }
    ticks++;
    nanosleep(&period, NULL);
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
  running = 1;
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
void fakehd_set_fault(int device, int on) { dev[device].fault = on; }
double fakehd_max_force(int device) { return dev[device].max_force_sent; }
long fakehd_frames(int device) { return dev[device].frames; }
long fakehd_ticks(void) { return ticks; }
int fakehd_in_frame(int device) { return dev[device].in_frame; }
int fakehd_force_enabled(int device) { return dev[device].force_output; }
int fakehd_ramping(int device) { return dev[device].ramping; }
