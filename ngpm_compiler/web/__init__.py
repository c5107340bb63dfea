"""`ngpmc serve`: a local web page to sketch a shape and watch a guided vine grow into it.

`app.create_app(config)` builds the Starlette application; `config.load_config(...)` gathers
the grammars and guides it offers. Needs the `[web]` extra (starlette, uvicorn).
"""
