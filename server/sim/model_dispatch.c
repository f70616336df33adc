/*
 * model_dispatch.c: which window function runs a non-persson model, how much
 * scratch it needs and which inputs (depth, base heights) the engine must
 * prepare — so the engine allocates only what the scene's models use. The
 * model comes from the params of the window, not from the engine, so a
 * per-cell material layer can route windows by material. Adding a model
 * is one case in each switch.
 */
#include "sim/sim_internal.h"

int64_t sim_model_scratch_cells(sim_model m, int64_t cells)
{
    switch (m) {
    case SIM_MODEL_SUBTRACT:
        return 0;
    case SIM_MODEL_DEFERRED:
        return 2 * cells; /* deformation and foot images */
    case SIM_MODEL_DIFFUSION:
        return 10 * cells +
               2; /* the larger of the two forms: Gilardi's doubles, + a slice's depth */
    case SIM_MODEL_DECALS:
        return cells; /* one collider's depth */
    case SIM_MODEL_SUMNER:
        return 14 * cells + 2; /* as sim_sumner_scratch_cells */
    case SIM_MODEL_BEKKER:
        return 29 * cells + (cells + 3) / 4 + 4; /* as sim_bekker_scratch_cells */
    case SIM_MODEL_PERSSON_ITERATIVE:
    case SIM_MODEL_PERSSON_SSBO:
    case SIM_MODEL_PERSSON_MULTI:
        break;
    }
    return 0;
}

int sim_model_needs_depth(sim_model m)
{
    return m == SIM_MODEL_DIFFUSION; /* subtract casts into the heights themselves */
}

int sim_model_needs_base(const sim_params *p)
{
    return (p->model == SIM_MODEL_SUBTRACT && p->refill_q16_per_tick > 0) ||
           p->model == SIM_MODEL_DEFERRED;
}

sim_window_status sim_model_window(const sim_params *p, sim_window_job *job, int32_t *scratch)
{
    switch (p->model) {
    case SIM_MODEL_SUBTRACT:
        return sim_subtract_window(p, job, scratch);
    case SIM_MODEL_DEFERRED:
        return sim_deferred_window(p, job, scratch);
    case SIM_MODEL_DIFFUSION:
        return sim_diffusion_window(p, job, scratch);
    case SIM_MODEL_DECALS: /* the engine collects its events; heights stay */
    case SIM_MODEL_SUMNER:
        return sim_sumner_window(p, job, scratch);
    case SIM_MODEL_BEKKER:
        return sim_bekker_window(p, job, scratch);
    case SIM_MODEL_PERSSON_ITERATIVE:
    case SIM_MODEL_PERSSON_SSBO:
    case SIM_MODEL_PERSSON_MULTI:
        break;
    }
    return SIM_WINDOW_OK;
}
