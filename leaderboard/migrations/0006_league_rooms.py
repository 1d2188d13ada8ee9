# Issue 48 (the race code's rooms): a bracket's results have one home, its BracketMatch rows.
# An event's ``bracket`` field kept the whole draw as JSON beside the rows; it now keeps only
# the seeding ({"seeds": [...], "withdrawn": [...]}). Every non-bye winner recorded in the
# JSON is carried to its match row first (the two always agreed; this loses nothing if not).

from django.db import migrations


def forwards(apps, schema_editor):
    Event = apps.get_model("leaderboard", "Event")
    BracketMatch = apps.get_model("leaderboard", "BracketMatch")
    for event in Event.objects.exclude(bracket={}):
        data = event.bracket or {}
        if "bracket" not in data:
            continue
        seeds = list(data.get("seeds", []))
        for games in data["bracket"].get("rounds", []):
            for game in games:
                winner = game.get("winner")
                if game.get("bye") or winner is None or not 1 <= winner <= len(seeds):
                    continue
                top, bottom = game.get("top"), game.get("bottom")
                match, _ = BracketMatch.objects.get_or_create(
                    event=event, round=game["round"], index=game["index"],
                    defaults={
                        "top_id": seeds[top - 1] if top else None,
                        "bottom_id": seeds[bottom - 1] if bottom else None,
                    },
                )
                if match.winner_id is None:
                    match.winner_id = seeds[winner - 1]
                    match.save(update_fields=["winner"])
        event.bracket = {"seeds": seeds, "withdrawn": list(data.get("withdrawn", []))}
        event.save(update_fields=["bracket"])


def backwards(apps, schema_editor):
    """Rebuild the JSON draw from the seeding and the rows (the old code's shape)."""
    from leaderboard import bracket_draw

    Event = apps.get_model("leaderboard", "Event")
    BracketMatch = apps.get_model("leaderboard", "BracketMatch")
    for event in Event.objects.exclude(bracket={}):
        data = event.bracket or {}
        seeds = list(data.get("seeds", []))
        if "bracket" in data or len(seeds) < 2:
            continue
        draw = bracket_draw.seed_bracket(len(seeds))
        for match in BracketMatch.objects.filter(event=event, winner__isnull=False).order_by(
            "round", "index"
        ):
            if match.winner_id in seeds:
                draw = bracket_draw.record_winner(
                    draw, match.round, match.index, seeds.index(match.winner_id) + 1
                )
        event.bracket = {**data, "bracket": draw.to_dict()}
        event.save(update_fields=["bracket"])


class Migration(migrations.Migration):

    dependencies = [
        ('leaderboard', '0005_live_speed'),
    ]

    operations = [
        migrations.RunPython(forwards, backwards),
    ]
