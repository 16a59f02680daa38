"""Studies: families of runs that a sweep's methods x h x initial-condition grid cannot express.

`vcirun study CONFIG` runs one (`runner.run_file`); `vcirun validate CONFIG` checks it (`schema.load_any`).

| module | owns |
|---|---|
| `schema` | the validated study configs (`study: work_precision`, `long_horizon`, `extremes`) |
| `runner` | loading, dispatch to the study's runner, saving the JSON results and the report |
| `outcome` | a run that never raises: status or the rejection / crash as a record |
| `step_size` | stable step range (scan + bisection), long-horizon energy drift |
| `contact` | hard contact cases: grazing, impact at a grid point, several impacts per step, start on the surface, impact accumulation |
| `parameters` | high energy, mass ratios, nearly singular mass matrix |
| `hygiene` | the whole loop uncompiled under np.errstate(all="raise") |
| `extremes` | the extremes study: each config section through the functions above |
| `report` | docs/extremes.md from the results and a Markdown template (prose lives in docs/templates/) |
| `wp_model` | a scene's work-precision model (error constants, cost per step) from a study's or a sweep's results, and the method and h it predicts for a tolerance |

The work-precision study's runner and analysis are `vcirun.experiments.workprecision`. Exact closed
forms (the bouncing ball, the oscillator against a wall) are `vcirun.scenes.oracles`.

Nothing is imported here: `import vcirun.experiments.studies.schema` does not load the runners.
"""
