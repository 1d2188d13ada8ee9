"""The "Race facilitators" group: create and run events, see every submission."""

from django.db import migrations

GROUP = "Race facilitators"
PERMISSIONS = [
    ("leaderboard", "add_event"), ("leaderboard", "change_event"), ("leaderboard", "view_event"),
    ("leaderboard", "add_season"), ("leaderboard", "change_season"),
    ("leaderboard", "view_season"), ("leaderboard", "view_submission"),
    ("leaderboard", "view_racerprofile"), ("leaderboard", "view_evententrant"),
]


def create_group(apps, schema_editor):
    Group = apps.get_model("auth", "Group")
    Permission = apps.get_model("auth", "Permission")
    group, _ = Group.objects.get_or_create(name=GROUP)
    # Permissions exist only after post_migrate on a fresh database; the group is what the
    # league checks, the permissions only open the admin pages to facilitators who are staff.
    for app_label, codename in PERMISSIONS:
        perm = Permission.objects.filter(
            content_type__app_label=app_label, codename=codename
        ).first()
        if perm is not None:
            group.permissions.add(perm)


def remove_group(apps, schema_editor):
    apps.get_model("auth", "Group").objects.filter(name=GROUP).delete()


class Migration(migrations.Migration):
    dependencies = [
        ("leaderboard", "0001_initial"),
        ("auth", "0012_alter_user_first_name_max_length"),
    ]

    operations = [migrations.RunPython(create_group, remove_group)]
