import os

import jax

os.environ.setdefault("CSTIFFJAX_CACHE_DIR", "off")  # tests never write a compilation cache into $HOME

jax.config.update("jax_enable_x64", True)
