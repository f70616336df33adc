// drive.go: terrad from Go over the C client library by cgo (docs/engines.md "Go"): connect,
// subscribe a window, predict it, drive a sphere through it, and check that the prediction was
// exact and that the mirror holds the rut.
//
//	CGO_CFLAGS="$(pkg-config --cflags terrad-client)" \
//	CGO_LDFLAGS="$(pkg-config --libs terrad-client)" go build -o drive .
//	./drive PORT X Y W H "model=persson-ssbo margin_cells=4 terrain.height_m=0.4" mirror.raw
//
// The last argument (optional) is where the mirror's heights go (int32, little-endian), for
// tests/integration/clients/test_go_example.py to compare with GET /v1/heights. Exit status 1 when a
// check fails. One client from one goroutine, locked to its thread, as the C library asks.
package main

/*
#cgo LDFLAGS: -lterrad-client
#include <stdlib.h>
#include <terrad/terrad_client.h>
*/
import "C"

import (
	"encoding/binary"
	"fmt"
	"os"
	"runtime"
	"strconv"
	"time"
	"unsafe"
)

func fail(format string, args ...interface{}) {
	fmt.Printf("FAIL "+format+"\n", args...)
	os.Exit(1)
}

func atoi(s string) int {
	v, err := strconv.Atoi(s)
	if err != nil {
		fail("%q is not a number", s)
	}
	return v
}

func main() {
	runtime.LockOSThread()
	if len(os.Args) < 7 {
		fmt.Fprintln(os.Stderr, "usage: drive PORT X Y W H CONFIG [OUT]")
		os.Exit(2)
	}
	port, x, y := atoi(os.Args[1]), atoi(os.Args[2]), atoi(os.Args[3])
	w, h := atoi(os.Args[4]), atoi(os.Args[5])

	name := C.CString("terrad-go")
	defer C.free(unsafe.Pointer(name))
	var errbuf [256]C.char
	desc := C.terrad_client_desc{port: C.int(port), name: name, timeout_ms: 120000}
	c := C.terrad_client_connect_world(desc, nil, &errbuf[0], C.size_t(len(errbuf)))
	if c == nil {
		fail("connect: %s", C.GoString(&errbuf[0]))
	}
	defer C.terrad_client_close(c)
	last := func() string { return C.GoString(C.terrad_client_last_error(c)) }
	world := C.terrad_client_world(c)

	var sid C.uint32_t
	if rc := C.terrad_client_subscribe(c, C.int32_t(x), C.int32_t(y), C.uint32_t(w), C.uint32_t(h), &sid); rc != 0 {
		fail("subscribe: %s", last())
	}
	for end := time.Now().Add(2 * time.Minute); C.terrad_client_mirror_complete(c, sid) == 0; {
		if time.Now().After(end) {
			fail("no snapshot")
		}
		C.terrad_client_poll(c, 20)
	}
	bad := C.CString(os.Args[6] + " model=nope")
	var pred *C.terrad_prediction
	rc := C.terrad_client_predict(c, sid, bad, &pred)
	C.free(unsafe.Pointer(bad))
	if rc == 0 {
		fail("an unknown model was taken")
	}
	fmt.Printf("refused as it should be: %s\n", last())
	config := C.CString(os.Args[6])
	defer C.free(unsafe.Pointer(config))
	if rc := C.terrad_client_predict(c, sid, config, &pred); rc != 0 {
		fail("predict: %s", last())
	}
	var ball C.uint32_t
	sphere := C.terrad_collider_desc{shape: C.TERRAD_SHAPE_SPHERE, radius: 0.3}
	if rc := C.terrad_client_create_collider(c, sphere, &ball); rc != 0 {
		fail("collider: %s", last())
	}

	// One pose batch a tick, along x through the window with a 24-cell halo at both ends.
	cell, hz := float64(world.cell_size_m), float64(world.tick_hz)
	x0, x1 := float64(x+24)*cell, float64(x+w-24)*cell
	row := y + h/2
	n := 240
	var seq C.uint32_t
	next := time.Now()
	for i := 0; i <= n; i++ {
		k, z := i, 0.4+0.3-0.06
		if i == n {
			k, z = n-1, z+5 // lifted
		}
		pose := []C.terrad_pose{{id: ball, x: C.float(x0 + (x1-x0)*float64(k)/float64(n-1)),
			y: C.float((float64(row) + 0.5) * cell), z: C.float(z), qw: 1}}
		if rc := C.terrad_client_send_poses(c, &pose[0], 1, &seq); rc != 0 {
			fail("send: %s", last())
		}
		next = next.Add(time.Duration(float64(time.Second) / hz))
		for time.Now().Before(next) {
			C.terrad_client_poll(c, 2)
		}
	}
	waitAck := func(seq C.uint32_t) {
		for end := time.Now().Add(2 * time.Minute); int32(C.terrad_client_get_stats(c).ack_seq-seq) < 0; {
			if time.Now().After(end) {
				fail("no ACK of batch %d", seq)
			}
			C.terrad_client_poll(c, 20)
		}
	}
	// A predicted collider leaves the prediction when it is deleted: delete it once its last
	// batch is acknowledged, or the replay of that batch's tick misses it.
	waitAck(seq)
	C.terrad_client_delete_collider(c, ball)
	C.terrad_client_send_poses(c, nil, 0, &seq) // an ACK after the deletion
	waitAck(seq)

	s := C.terrad_client_get_stats(c)
	ps := C.terrad_prediction_get_stats(pred)
	m := C.terrad_client_mirror(c, sid)
	cells := w * h
	mirror := unsafe.Slice((*int32)(unsafe.Pointer(m.heights)), cells)
	predicted := unsafe.Slice((*int32)(unsafe.Pointer(C.terrad_prediction_heights(pred))), cells)
	deepest, top := mirror[(row-y)*w], mirror[(row-y)*w]
	for _, v := range mirror[(row-y)*w : (row-y+1)*w] {
		if v < deepest {
			deepest = v
		}
	}
	same := true
	for i := range mirror {
		same = same && mirror[i] == predicted[i]
	}
	fmt.Printf("drove %d ticks: %d DELTA frames, %d ACKs; prediction: %d compared, %d exact; rut %d units deep\n",
		n, s.delta_frames, s.acks, ps.replayed, ps.exact, top-deepest)
	if ps.replayed < 10 || ps.exact != ps.replayed {
		fail("the prediction was not exact at every compared ACK (%d of %d)", ps.exact, ps.replayed)
	}
	if ps.errors != 0 {
		fail("the twin failed on %d of the prediction's events", ps.errors)
	}
	if !same || top-deepest < int32(world.units_per_m)/50 {
		fail("the mirror holds no rut, or the prediction differs from it")
	}
	if len(os.Args) > 7 {
		f, err := os.Create(os.Args[7])
		if err != nil {
			fail("%v", err)
		}
		if err := binary.Write(f, binary.LittleEndian, mirror); err != nil {
			fail("%v", err)
		}
		f.Close()
	}
	fmt.Println("ok")
}
