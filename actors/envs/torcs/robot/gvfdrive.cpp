/*
 * gvfdrive: the TORCS robot that Python drives in lockstep (gvf-drive issue 15, stage 2).
 *
 * TORCS calls a robot's drive() every 0.02 s of simulated time (every 10th 0.002 s physics step;
 * deploy/torcs/patches/gvf-robot-period.patch keeps that period exact). One control step of the
 * Python side is CALLS_PER_STEP = 5 calls = 0.1 s: at the first call of a step the robot writes
 * the car's state to its output pipe and blocks until Python writes the action; it then holds that
 * action for the 5 calls, so the race runs exactly as fast as Python steps it (no real-time pacing).
 *
 * Pipes: Python passes two inherited file descriptors in the environment, GVF_TORCS_FDS="in,out"
 * (in: actions from Python, out: states to Python). End of file on "in" (Python closed it or died)
 * ends the process, so no TORCS is ever left waiting for a peer that is gone.
 *
 * Wire format (little-endian, fixed size, the same layout as actors/envs/torcs/protocol.py):
 *   GvfState  (robot -> Python): see the struct below, STATE_SIZE bytes.
 *   GvfAction (Python -> robot): magic, command (0 drive, 1 quit), steer in [-1, 1] (+ turns left,
 *             TORCS's sign), target speed in m/s (the robot's speed controller turns it into
 *             throttle, brake and gear).
 */

#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <tgf.h>
#include <track.h>
#include <car.h>
#include <raceman.h>
#include <robottools.h>
#include <robot.h>

// Calls of drive() per control step: 5 x 0.02 s = 0.1 s of simulated time.
static const int CALLS_PER_STEP = 5;

// 'GVFS' and 'GVFA' as little-endian integers: a reader that finds anything else is out of step.
static const uint32_t STATE_MAGIC = 0x53465647u;
static const uint32_t ACTION_MAGIC = 0x41465647u;
// Bumped whenever a field of GvfState or GvfAction changes.
static const uint32_t PROTOCOL_VERSION = 1u;

enum { COMMAND_DRIVE = 0, COMMAND_QUIT = 1 };

// The car's state at the first drive() call of a control step. Doubles first, then 32-bit
// integers in an even number, so the struct has no padding on any ABI TORCS builds on.
struct GvfState {
	uint32_t magic;
	uint32_t version;
	uint64_t step;              // control steps since this race started (0 = the first state)
	double time;                // simulated race time, s (s->currentTime)
	double x, y, z;             // position of the car's centre of gravity, m (track frame)
	double yaw;                 // heading, rad, in [0, 2 pi)
	double speed;               // longitudinal speed, m/s (car frame)
	double speed_lateral;       // lateral speed, m/s (car frame, + left)
	double yaw_rate;            // rad/s
	double to_middle;           // distance from the road's middle, m (+ left), TORCS's toMiddle
	double to_left;             // distance to the left edge, m (negative outside the road)
	double to_right;            // distance to the right edge, m
	double angle;               // road direction minus yaw, rad, in [-pi, pi)
	double dist_from_start;     // distance along the road from the start line, m (distFromStartLine)
	double dist_raced;          // TORCS's distRaced, m (negative until the start line is first crossed)
	double track_length;        // length of the road's middle line, m
	double seg_curvature;       // signed curvature of the current segment's middle, 1/m (+ left)
	double seg_width;           // road width at the current segment, m
	double steer;               // steering command applied over the last calls (the held action)
	double target_speed;        // target speed held over the last calls, m/s
	double accel;               // throttle command of the last call, [0, 1]
	double brake;               // brake command of the last call, [0, 1]
	int32_t seg_id;             // TORCS's segment number
	int32_t seg_type;           // 1 right turn, 2 left turn, 3 straight (TR_RGT, TR_LFT, TR_STR)
	int32_t lap;                // start-line crossings so far (TORCS's laps; 0 until the first one)
	int32_t damage;             // TORCS's damage points
	int32_t gear;               // current gear (-1 reverse, 0 neutral)
	int32_t state;              // TORCS's car state flags (RM_CAR_STATE_*)
};

struct GvfAction {
	uint32_t magic;
	uint32_t command;
	double steer;
	double target_speed;
};

static_assert(sizeof(GvfState) == 8 + 8 + 21 * 8 + 6 * 4, "GvfState must have no padding");
static_assert(sizeof(GvfAction) == 24, "GvfAction must have no padding");

// One robot per process: the race files that Python writes hold exactly one driver.
static int fdIn = -1;
static int fdOut = -1;
static tTrack *curTrack = NULL;
static uint64_t stepCount = 0;
static int callsLeft = 0;
static GvfAction held;
static double lastAccel = 0.0;
static double lastBrake = 0.0;
static double throttleIntegral = 0.0;

// Reads or writes exactly n bytes; false on end of file or error (the peer is gone).
static bool readAll(int fd, void *buf, size_t n)
{
	char *p = (char *)buf;
	while (n > 0) {
		ssize_t r = read(fd, p, n);
		if (r < 0 && errno == EINTR) {
			continue;
		}
		if (r <= 0) {
			return false;
		}
		p += r;
		n -= (size_t)r;
	}
	return true;
}

static bool writeAll(int fd, const void *buf, size_t n)
{
	const char *p = (const char *)buf;
	while (n > 0) {
		ssize_t r = write(fd, p, n);
		if (r < 0 && errno == EINTR) {
			continue;
		}
		if (r <= 0) {
			return false;
		}
		p += r;
		n -= (size_t)r;
	}
	return true;
}

// Python gone or out of step: nothing useful can follow, and exiting frees the peer's pipes.
static void quit(const char *why)
{
	fprintf(stderr, "gvfdrive: %s, exiting\n", why);
	fflush(stderr);
	_exit(0);
}

static void openPipes(void)
{
	const char *fds = getenv("GVF_TORCS_FDS");
	if (fds == NULL || sscanf(fds, "%d,%d", &fdIn, &fdOut) != 2) {
		quit("GVF_TORCS_FDS is not set to \"in,out\" (start TORCS through actors.envs.torcs.protocol)");
	}
}

// Signed curvature of the segment's middle line: + for left turns, as the steering sign.
static double segCurvature(const tTrackSeg *seg)
{
	if (seg->type == TR_STR || seg->radius <= 0.0) {
		return 0.0;
	}
	return (seg->type == TR_LFT ? 1.0 : -1.0) / seg->radius;
}

static void sendState(const tCarElt *car, const tSituation *s)
{
	GvfState st;
	memset(&st, 0, sizeof(st));
	const tTrackSeg *seg = car->_trkPos.seg;
	double angle = RtTrackSideTgAngleL((tTrkLocPos *)&car->_trkPos) - car->_yaw;
	NORM_PI_PI(angle);
	st.magic = STATE_MAGIC;
	st.version = PROTOCOL_VERSION;
	st.step = stepCount;
	st.time = s->currentTime;
	st.x = car->_pos_X;
	st.y = car->_pos_Y;
	st.z = car->_pos_Z;
	st.yaw = car->_yaw;
	st.speed = car->_speed_x;
	st.speed_lateral = car->_speed_y;
	st.yaw_rate = car->_yaw_rate;
	st.to_middle = car->_trkPos.toMiddle;
	st.to_left = car->_trkPos.toLeft;
	st.to_right = car->_trkPos.toRight;
	st.angle = angle;
	st.dist_from_start = car->_distFromStartLine;
	st.dist_raced = car->_distRaced;
	st.track_length = curTrack != NULL ? curTrack->length : 0.0;
	st.seg_curvature = segCurvature(seg);
	st.seg_width = seg->width;
	st.steer = held.steer;
	st.target_speed = held.target_speed;
	st.accel = lastAccel;
	st.brake = lastBrake;
	st.seg_id = seg->id;
	st.seg_type = seg->type;
	st.lap = car->_laps;
	st.damage = car->_dammage;
	st.gear = car->_gear;
	st.state = car->_state;
	if (!writeAll(fdOut, &st, sizeof(st))) {
		quit("cannot write the state (Python closed the pipe)");
	}
}

// TORCS's physics must never see NaN or an out-of-range command: NaN becomes 0, the rest is clipped.
static double clampFinite(double v, double lo, double hi)
{
	if (isnan(v)) {
		return 0.0;
	}
	return fmin(hi, fmax(lo, v));
}

static void receiveAction(void)
{
	GvfAction a;
	if (!readAll(fdIn, &a, sizeof(a))) {
		quit("end of the action pipe");
	}
	if (a.magic != ACTION_MAGIC) {
		quit("bad action magic");
	}
	if (a.command == COMMAND_QUIT) {
		quit("asked to quit");
	}
	a.steer = clampFinite(a.steer, -1.0, 1.0);
	a.target_speed = clampFinite(a.target_speed, 0.0, 1000.0);
	held = a;
}

// Gear from the speed at which the engine would pass its red line: up near it, down well below it.
static int chooseGear(const tCarElt *car)
{
	const double SHIFT = 0.9;          // shift up at 90% of the red line
	const double SHIFT_MARGIN = 4.0;   // m/s of hysteresis before shifting down
	int gear = car->_gear;
	if (gear <= 0) {
		return 1;
	}
	double wheelRadius = car->_wheelRadius(REAR_RGT);
	double upSpeed = car->_enginerpmRedLine / car->_gearRatio[gear + car->_gearOffset] * wheelRadius;
	if (gear + car->_gearOffset < car->_gearNb - 1 && car->_speed_x > SHIFT * upSpeed) {
		return gear + 1;
	}
	if (gear > 1) {
		double downSpeed = car->_enginerpmRedLine / car->_gearRatio[gear - 1 + car->_gearOffset] * wheelRadius;
		if (car->_speed_x < SHIFT * downSpeed - SHIFT_MARGIN) {
			return gear - 1;
		}
	}
	return gear;
}

// Speed control: proportional-integral throttle (the integral holds the throttle that drag needs,
// so the car settles on the target instead of below it), and brakes only 1 m/s or more above it.
static void applyAction(tCarElt *car, double dt)
{
	const double KP = 0.5, KI = 0.5, BRAKE_MARGIN = 1.0, BRAKE_GAIN = 0.2;
	double err = held.target_speed - car->_speed_x;
	// The integral moves only while the throttle it gives is inside (0, 1): no wind-up during a
	// full-throttle climb to a far target, which would overshoot it.
	double integral = fmax(0.0, throttleIntegral + err * dt);
	double unclipped = KP * err + KI * integral;
	if (unclipped > 0.0 && unclipped < 1.0) {
		throttleIntegral = integral;
	}
	double accel = fmin(1.0, fmax(0.0, KP * err + KI * throttleIntegral));
	double brake = err < -BRAKE_MARGIN ? fmin(1.0, BRAKE_GAIN * (-err - BRAKE_MARGIN)) : 0.0;
	if (brake > 0.0) {
		accel = 0.0;
	}
	car->_steerCmd = (tdble)held.steer;
	car->_accelCmd = (tdble)accel;
	car->_brakeCmd = (tdble)brake;
	car->_gearCmd = chooseGear(car);
	car->_clutchCmd = 0.0;
	lastAccel = accel;
	lastBrake = brake;
}

static void initTrack(int index, tTrack *track, void *carHandle, void **carParmHandle, tSituation *s)
{
	curTrack = track;
	*carParmHandle = NULL;  // the car's default setup: every episode drives the same car
}

static void newRace(int index, tCarElt *car, tSituation *s)
{
	openPipes();
	stepCount = 0;
	callsLeft = 0;
	throttleIntegral = 0.0;
	memset(&held, 0, sizeof(held));
}

static void drive(int index, tCarElt *car, tSituation *s)
{
	memset(&car->ctrl, 0, sizeof(tCarCtrl));
	if (s->currentTime < 0.0) {
		// The countdown before the start: the physics hold the car, Python sees only the race.
		car->_brakeCmd = 1.0;
		return;
	}
	if (callsLeft == 0) {
		sendState(car, s);
		receiveAction();
		stepCount++;
		callsLeft = CALLS_PER_STEP;
	}
	applyAction(car, s->deltaTime);
	callsLeft--;
}

static int pitCmd(int index, tCarElt *car, tSituation *s)
{
	return ROB_PIT_IM;
}

static void endRace(int index, tCarElt *car, tSituation *s)
{
}

static void shutdown(int index)
{
}

static int initFuncPt(int index, void *pt)
{
	tRobotItf *itf = (tRobotItf *)pt;
	itf->rbNewTrack = initTrack;
	itf->rbNewRace = newRace;
	itf->rbDrive = drive;
	itf->rbPitCmd = pitCmd;
	itf->rbEndRace = endRace;
	itf->rbShutdown = shutdown;
	itf->index = index;
	return 0;
}

// Module entry point: TORCS looks the function up by the library's file name.
extern "C" int gvfdrive(tModInfo *modInfo)
{
	memset(modInfo, 0, 10 * sizeof(tModInfo));
	modInfo[0].name = strdup("gvfdrive 1");
	modInfo[0].desc = strdup("driven step by step from Python (gvf-drive)");
	modInfo[0].fctInit = initFuncPt;
	modInfo[0].gfId = ROB_IDENT;
	modInfo[0].index = 0;
	return 0;
}
