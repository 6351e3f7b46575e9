"""Pipeline stages (installed as ``go_pipeline.steps``): one module per stage, each a pure function
``run(ctx, inputs, params)`` of its input artifacts and params that writes its artifacts into ``ctx.out_dir``.
"""
