/*
 * twin_rut.c: the twin library (libterrad-twin, docs/engines.md) on its own —
 * a 64 x 64 window of 0.4 m flat snow in a 256 x 256 world of 5 cm cells, a
 * sphere rolled east across it for 60 ticks, then the rut's depth printed.
 * No daemon: this is what a client runs locally to show its own rut before
 * the server's deltas arrive.
 *
 *   cc twin_rut.c $(pkg-config --cflags --libs terrad-twin) -o twin_rut
 */
#include <stdio.h>

#include <terrad/terrad_twin.h>

int main(void)
{
    char err[TERRAD_TWIN_ERROR_MAX];
    terrad_twin_config *c = terrad_twin_config_new();
    if (!c || terrad_twin_config_set(c, "width", 256, err) != 0 ||
        terrad_twin_config_set(c, "height", 256, err) != 0 ||
        terrad_twin_config_set(c, "terrain.height_m", 0.4, err) != 0) {
        fprintf(stderr, "twin_rut: %s\n", err);
        return 1;
    }
    /* The window [96, 160) x [96, 160): its heights are the base terrain. */
    terrad_twin *t = terrad_twin_create(c, 96, 96, 64, 64, NULL, err);
    terrad_twin_config_free(c);
    if (!t || terrad_twin_add_collider(t, 1, "sphere", 0.3, 0, 0, 0, 0, err) != 0) {
        fprintf(stderr, "twin_rut: %s\n", err);
        return 1;
    }
    for (int tick = 0; tick < 60; tick++) {
        double x = 5.5 + tick * 0.02; /* metres: 1.2 m/s at 60 ticks per second */
        if (terrad_twin_set_pose(t, 1, x, 6.4, 0.65, 1, 0, 0, 0, err) != 0 ||
            terrad_twin_tick(t, err) != 0) {
            fprintf(stderr, "twin_rut: tick %d: %s\n", tick, err);
            return 1;
        }
    }
    int32_t row[64];
    if (terrad_twin_read(t, 96, 128, 64, 1, row, err) != 0) {
        fprintf(stderr, "twin_rut: %s\n", err);
        return 1;
    }
    int32_t lowest = row[0];
    for (int i = 1; i < 64; i++)
        lowest = row[i] < lowest ? row[i] : lowest;
    printf("rut: lowest cell of row 128 at %.4f m (flat snow at 0.4000 m)\n", lowest / 10000.0);
    terrad_twin_destroy(t);
    return lowest < 4000 ? 0 : 1;
}
