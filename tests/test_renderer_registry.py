"""The renderer table's command-line help says the defaults the renderers use."""

import re

from zcomp_cli.renderers.registry import BUILTIN_RENDERERS


def test_the_batch_size_help_states_the_renderers_default():
    from zcomp_cli.renderers.zerocomp.renderer import DEFAULT_BATCH_SIZE

    (opt,) = [o for o in BUILTIN_RENDERERS["zerocomp"].options if o.setting == "batch_size"]
    stated = re.search(r"default (\d+)", opt.help)
    assert stated is not None and int(stated.group(1)) == DEFAULT_BATCH_SIZE, opt.help
