"""A simulated speaker in front of a simulated iPhone: paired speech, ARKit blendshapes and phone
alignments, written as Live Link Face take folders (``s2a-capture simulate``)."""

# Imported on first use (PEP 562): ``s2a-capture`` registers the subcommand through this package, and
# every other subcommand would otherwise pay for importing scipy.signal (about a second) at start-up.
_EXPORTS = {
    "Articulation": "articulation",
    "articulate": "articulation",
    "ARTIFACT_NAMES": "artifacts",
    "Artifacts": "artifacts",
    "INVENTORIES": "phones",
    "Inventory": "phones",
    "Phone": "phones",
    "inventory": "phones",
    "viseme_matrix": "phones",
    "Utterance": "prosody",
    "plan_utterance": "prosody",
    "SIMULATION_FILE": "session",
    "SimulatedTake": "session",
    "TakeSpec": "session",
    "plan_session": "session",
    "simulate": "session",
    "simulate_take": "session",
    "write_take_folder": "session",
    "Speaker": "speaker",
    "draw_speaker": "speaker",
    "synthesize": "voice",
}


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


__all__ = [
    "ARTIFACT_NAMES",
    "Articulation",
    "Artifacts",
    "INVENTORIES",
    "Inventory",
    "Phone",
    "SIMULATION_FILE",
    "SimulatedTake",
    "Speaker",
    "TakeSpec",
    "Utterance",
    "articulate",
    "draw_speaker",
    "inventory",
    "plan_session",
    "plan_utterance",
    "simulate",
    "simulate_take",
    "synthesize",
    "viseme_matrix",
    "write_take_folder",
]
