"""samp's MLflow experiments are marked as model training, so MLflow's UI opens them in its training layout
(runs, metrics, charts) instead of its GenAI one (issue 53). Read back from a real local store with MLflow's
own client; the tag's key and value are those MLflow 3's UI reads (`mlflow.experimentKind`)."""

from __future__ import annotations

from samp.names import TRACKING_DB
from samp.tracking import EXPERIMENT_KIND, client, experiment_id

KIND = "mlflow.experimentKind"


def test_new_and_reused_experiments_are_marked_as_model_training(tmp_path):
    assert EXPERIMENT_KIND == (KIND, "custom_model_development")
    uri = f"sqlite:///{tmp_path / TRACKING_DB}"
    mlflow_client = client(uri)
    made = experiment_id(mlflow_client, uri, "quickstart")
    older = mlflow_client.create_experiment("older")  # made before samp set the kind
    mine = mlflow_client.create_experiment("mine", tags={KIND: "genai_development"})  # a user's own choice

    assert experiment_id(mlflow_client, uri, "older") == older and experiment_id(mlflow_client, uri, "mine") == mine
    kinds = {name: client(uri).get_experiment(ident).tags.get(KIND)
             for name, ident in {"quickstart": made, "older": older, "mine": mine}.items()}
    assert kinds == {"quickstart": "custom_model_development", "older": "custom_model_development",
                     "mine": "genai_development"}, kinds
